"""FSPF and FSPF+ in numpy only: the reference versions tools/bench_planes.py times beside the compiled filters of
frontend/fspf.py, to show what compiling buys (docs/dependencies.md). The same algorithms, vectorised per window:
the same steps and tests, not the same random draws (RANSAC scores hypotheses in batches and refits on all
inliers), and neither the coherence test nor growing. The classes, dropping and merging are fspf.py's."""

from __future__ import annotations


import numpy as np

from kosmap.frontend.camera import DepthConfig, depth_constraints
from kosmap.frontend.fspf import FspfConfig, framed
from kosmap.frontend.planes import FrameStats, Planes, fit_plane, ransac_plane, rectify
from kosmap.frontend.records import CameraModel, Transform


def filter_planes_numpy(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None,
                        depth_cfg: DepthConfig | None = None, mount: Transform | None = None,
                        seed: int | None = None) -> Planes:
    """FSPF+ or FSPF in numpy, as `cfg.method` says (the arguments of frontend.fspf.filter_planes)."""
    cfg = cfg or FspfConfig()
    kernel = fspf_numpy if cfg.method == "fspf" else fspf_plus_numpy
    return framed(kernel, depth_m, cam, cfg, depth_cfg, mount, seed)


def fspf_plus_numpy(depth, cam, cfg, dcfg, classes_of, drop, rng):
    H, W = depth.shape
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    elig = depth_constraints(depth, dcfg.min_depth, dcfg.max_depth)
    st = elig.astype(np.uint8)
    cand = np.flatnonzero(elig)
    n_elig = len(cand)
    remaining = n_elig
    stop = (1.0 - cfg.analysed_fraction) * n_elig
    om = cfg.omega_px
    pix, pts, plane, normals, offsets, classes, counts = [], [], [], [], [], [], []
    n_drop = n_outl = 0
    flat_st = st.reshape(-1)
    misses = 0
    while remaining > stop and len(cand):
        i0 = int(cand[rng.integers(len(cand))])
        if flat_st[i0] != 1:
            misses += 1
            if misses > 16:  # compact the candidates once many have been consumed
                cand = cand[flat_st[cand] == 1]
                misses = 0
            continue
        r0, c0 = divmod(i0, W)
        off = rng.integers(-om, om + 1, (40, 2))
        rr, cc = r0 + off[:, 0], c0 + off[:, 1]
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        rr, cc = rr[ok], cc[ok]
        jj = rr * W + cc
        ok = (flat_st[jj] == 1) & (jj != i0)
        jj = jj[ok]
        _, first = np.unique(jj, return_index=True)
        jj = jj[np.sort(first)][:2]
        if len(jj) < 2:
            flat_st[i0] = 2
            remaining -= 1
            n_outl += 1
            continue
        zbar = (depth.flat[i0] + depth.flat[jj[0]] + depth.flat[jj[1]]) / 3.0
        hw, hh = int(0.5 * fx * cfg.delta_m / zbar + 0.5), int(0.5 * fy * cfg.delta_m / zbar + 0.5)
        r_lo, r_hi, c_lo, c_hi = max(0, r0 - hh), min(H - 1, r0 + hh), max(0, c0 - hw), min(W - 1, c0 + hw)
        win = st[r_lo:r_hi + 1, c_lo:c_hi + 1]
        m = win == 1
        wr, wc = np.nonzero(m)
        win[m] = 2
        k = len(wr)
        remaining -= k
        if k <= cfg.n_min:
            n_outl += k
            continue
        wr += r_lo
        wc += c_lo
        z = depth[wr, wc].astype(np.float64)
        P = np.column_stack(((wc - cx) * z / fx, (wr - cy) * z / fy, z))
        active = np.arange(k)
        eps = cfg.epsilon_m
        for pw in range(cfg.planes_per_window):
            if len(active) <= cfg.n_min or (pw > 0 and len(active) < cfg.extra_min_fraction * k):
                break
            n, d, inl = ransac_plane(P[active], eps, cfg.beta, rng, cfg.ransac_subset, cfg.ransac_max_iter)
            n_in = int(inl.sum())
            if n_in <= cfg.n_min:
                break
            # the noise tail (ε … tail_eps·ε) leaves the window as outliers
            res = np.abs(P[active] @ n + d)
            tail = ~inl & (res < max(cfg.tail_eps, 1.0) * eps)
            n_outl += int(tail.sum())
            cls = int(classes_of(n[None], np.array([d]))[0])
            sel = active[inl]
            active = active[~inl & ~tail]
            if drop[cls]:
                n_drop += n_in
                continue
            q = P[sel] - P[sel].mean(axis=0)
            ev = np.linalg.eigvalsh(q.T @ q / n_in)
            if ev[1] < (cfg.min_width * eps) ** 2 or (cfg.bend_max > 0 and ev[0] > (0.2 * eps) ** 2
                                                    and _bends(P[sel][:: max(1, n_in // 256)][:256], n, d, eps,
                                                               cfg.bend_max)):
                n_outl += n_in  # a thin strip, or a strip of a curved surface
                continue
            else:
                plane.append(np.full(n_in, len(normals), np.int32))
                pix.append(np.column_stack((wr[sel], wc[sel])).astype(np.int32))
                pts.append(P[sel].astype(np.float32))
                normals.append(n)
                offsets.append(d)
                classes.append(cls)
                counts.append(n_in)
        n_outl += len(active)
    stats = FrameStats(H * W, H * W - n_elig, int(sum(counts)), n_drop, n_outl, remaining)
    return _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, (H, W), "fspf+")


def _bends(p: np.ndarray, n: np.ndarray, d: float, eps: float, bend_max: float, r2_max: float = 0.5) -> bool:
    """_curved_nb in numpy: a quadratic in the in-plane coordinates explains > r2_max of the residuals and
    bends by more than bend_max·ε."""
    r = p @ n + d
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    u, v = (p - p.mean(axis=0)) @ e1, (p - p.mean(axis=0)) @ e2
    scale = max(np.abs(u).max(), np.abs(v).max(), 1e-12)
    u, v = u / scale, v / scale
    A = np.column_stack((np.ones_like(u), u, v, u * u, v * v, u * v))
    if len(r) < 24:
        return False
    coef = np.linalg.lstsq(A, r, rcond=None)[0]
    tot = np.sum((r - r.mean()) ** 2)
    if tot <= 0:
        return False
    bend = A[:, 3:] @ coef[3:]
    return 1.0 - np.sum((r - A @ coef) ** 2) / tot > r2_max and bend.max() - bend.min() > bend_max * eps


def fspf_numpy(depth, cam, cfg, dcfg, classes_of, drop, rng, batch: int = 256):
    """FSPF in numpy: neighbourhoods are drawn and tested a batch at a time; the accepted ones are then taken
    in order (they alone change the state), up to n_max points."""
    H, W = depth.shape
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    elig = depth_constraints(depth, dcfg.min_depth, dcfg.max_depth)
    st = elig.astype(np.uint8).reshape(-1)  # 0 ineligible, 1 eligible, 2 examined, 3 plane point, 4 dropped
    zf = depth.reshape(-1).astype(np.float64)
    l, eta, half = cfg.fspf_local_samples, cfg.fspf_window_px, cfg.fspf_window_px // 2
    need = int(np.ceil(cfg.fspf_min_inlier_fraction * l - 1e-9))
    pix, pts, plane, normals, offsets, classes, counts = [], [], [], [], [], [], []
    n_out = n_drop = 0
    done = 0
    while done < cfg.fspf_max_neighborhoods and n_out + n_drop < cfg.fspf_max_points:
        B = min(batch, cfg.fspf_max_neighborhoods - done)
        done += B
        rs = np.empty((B, 3), np.int64)
        cs = np.empty((B, 3), np.int64)
        rs[:, 0], cs[:, 0] = rng.integers(0, H, B), rng.integers(0, W, B)
        rs[:, 1:] = rs[:, :1] + rng.integers(0, eta + 1, (B, 2)) - half
        cs[:, 1:] = cs[:, :1] + rng.integers(0, eta + 1, (B, 2)) - half
        ok = ((rs >= 0) & (rs < H) & (cs >= 0) & (cs < W)).all(axis=1)
        rs, cs = rs[ok], cs[ok]
        j3 = rs * W + cs
        ok = (st[j3] != 0).all(axis=1)
        rs, cs, j3 = rs[ok], cs[ok], j3[ok]
        if not len(rs):
            continue
        z3 = zf[j3]
        p3 = np.stack(((cs - cx) * z3 / fx, (rs - cy) * z3 / fy, z3), axis=-1)  # K×3×3
        n = np.cross(p3[:, 1] - p3[:, 0], p3[:, 2] - p3[:, 0])
        nn = np.linalg.norm(n, axis=1)
        ok = nn > 1e-12
        if not ok.any():
            continue
        rs, cs, p3, n, nn, z3 = rs[ok], cs[ok], p3[ok], n[ok], nn[ok], z3[ok]
        n /= nn[:, None]
        d = -np.einsum("ij,ij->i", n, p3[:, 0])
        zbar = z3.mean(axis=1)
        u = rng.random((len(rs), l, 2)) - 0.5
        lr = rs[:, :1] + np.floor(u[..., 0] * (fy * cfg.delta_m / zbar)[:, None] + 0.5).astype(np.int64)
        lc = cs[:, :1] + np.floor(u[..., 1] * (fx * cfg.delta_m / zbar)[:, None] + 0.5).astype(np.int64)
        inside = (lr >= 0) & (lr < H) & (lc >= 0) & (lc < W)
        j = np.where(inside, lr * W + lc, 0)
        valid = inside & (st[j] != 0)
        z = zf[j]
        P = np.stack(((j % W - cx) * z / fx, (j // W - cy) * z / fy, z), axis=-1)  # K×l×3
        inl = valid & (np.abs(np.einsum("kij,kj->ki", P, n) + d[:, None]) < cfg.fspf_error_m)
        accepted = inl.sum(axis=1) >= need
        last = len(rs)
        for k in np.flatnonzero(accepted):
            if n_out + n_drop >= cfg.fspf_max_points:
                last = k
                break
            jk, Pk = j[k][inl[k]], P[k][inl[k]]
            nk, dk = rectify(*fit_plane(Pk))
            cls = int(classes_of(nk[None], np.array([dk]))[0])
            jk, first = np.unique(jk, return_index=True)
            Pk = Pk[first]
            new = (st[jk] == 1) | (st[jk] == 2)
            if drop[cls]:
                st[jk[new]] = 4
                n_drop += int(new.sum())
                continue
            if not new.any():
                continue
            jk, Pk = jk[new], Pk[new]
            st[jk] = 3
            plane.append(np.full(len(jk), len(normals), np.int32))
            pix.append(np.column_stack((jk // W, jk % W)).astype(np.int32))
            pts.append(Pk.astype(np.float32))
            normals.append(nk)
            offsets.append(float(dk))
            classes.append(cls)
            counts.append(len(jk))
            n_out += len(jk)
        # the rejected neighbourhoods before the stop: their examined samples are outliers
        rej = valid[:last] & ~accepted[:last, None]
        jr = j[:last][rej]
        st[jr[st[jr] == 1]] = 2
    stats = FrameStats(H * W, int((st == 0).sum()), n_out, n_drop, int((st == 2).sum()), int((st == 1).sum()))
    return _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, (H, W), "fspf")


def _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, shape, method) -> Planes:
    if not normals:
        return Planes.empty(shape, stats, method)
    return Planes(np.concatenate(pts), np.concatenate(plane), np.concatenate(pix), np.array(normals, float),
                  np.array(offsets, float), np.array(classes, np.int8), np.array(counts, np.int64), stats, shape, method)
