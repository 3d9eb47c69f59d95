"""Trajectory error: the Kümmerle et al. relations metric, and ATE / RPE against a ground truth (evo's definitions).

Relations (Kümmerle et al., "On measuring the accuracy of SLAM algorithms", Auton. Robots 2009): each line
`t1 t2 x y z roll pitch yaw` is the reference δ*_ij = x_t1⁻¹ ⊕ x_t2 between two scans. The error of a
relation is ε = δ*⁻¹ ⊕ δ with δ = x̂_t1⁻¹ ⊕ x̂_t2 the estimate; its translational error is ‖trans(ε)‖
(= ‖t − t*‖, both translations in the frame of x_t1) and its rotational error |wrap(θ − θ*)|. Reported, as
Hess et al. 2016 Table II: the absolute and the squared translational error (m, m²) and the absolute and
squared rotational error (deg, deg²), each as mean ± std (population std, ddof 0) over all relations.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.errors import KosmapError


class MetricsError(KosmapError):
    """A reference file that cannot be read or matched to the trajectory."""


def read_relations(path: str | Path) -> np.ndarray:
    """Relations as an M×5 array (t1, t2, x, y, yaw); t in seconds as in the file."""
    p = Path(path)
    if not p.is_file():
        raise MetricsError(f"relations file {p} does not exist; give a Kümmerle .relations file")
    rows = []
    for lineno, line in enumerate(p.read_text().splitlines(), 1):
        f = line.split()
        if not f or f[0].startswith("#"):
            continue
        if len(f) < 8:
            raise MetricsError(f"{p}:{lineno}: expected `t1 t2 x y z roll pitch yaw`, got {len(f)} fields")
        try:
            rows.append((float(f[0]), float(f[1]), float(f[2]), float(f[3]), float(f[7])))
        except ValueError as e:
            raise MetricsError(f"{p}:{lineno}: not a number ({e})") from e
    if not rows:
        raise MetricsError(f"{p} holds no relations")
    return np.array(rows)


def _lookup(stamps: np.ndarray, t: np.ndarray, tol: float) -> np.ndarray:
    """Index of the nearest stamp to each t, −1 where none is within tol seconds."""
    i = np.clip(np.searchsorted(stamps, t), 1, len(stamps) - 1)
    left = stamps[i - 1]
    right = stamps[i]
    j = np.where(np.abs(t - left) <= np.abs(right - t), i - 1, i)
    return np.where(np.abs(stamps[j] - t) <= tol, j, -1)


def relation_errors(stamps, poses, relations: np.ndarray, tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(translational errors m, rotational errors rad, mask of relations found) for poses at scan stamps (s)."""
    stamps = np.asarray(stamps, dtype=float)
    poses = np.asarray(poses, dtype=float)
    order = np.argsort(stamps)
    stamps, poses = stamps[order], poses[order]
    if len(stamps) < 2:
        raise MetricsError("the trajectory has fewer than two poses; nothing to score")
    i1 = _lookup(stamps, relations[:, 0], tol)
    i2 = _lookup(stamps, relations[:, 1], tol)
    ok = (i1 >= 0) & (i2 >= 0)
    est = se2.between(poses[i1[ok]], poses[i2[ok]])
    ref = relations[ok][:, 2:5]
    et = np.hypot(est[:, 0] - ref[:, 0], est[:, 1] - ref[:, 1])
    er = np.abs(se2.wrap(est[:, 2] - ref[:, 2]))
    return et, er, ok


def _in_gaps(stamps, relations: np.ndarray, tol: float) -> np.ndarray:
    """Per relation: every stamp of it that the trajectory lacks lies in a gap of the trajectory (between scans more
    than 3 median scan periods apart, or outside its span), as where a damaged or cut log lost its scans."""
    t = np.sort(np.asarray(stamps, dtype=float))
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out = np.ones(len(relations), bool)
    for col in (0, 1):
        q = relations[:, col]
        i = np.clip(np.searchsorted(t, q), 1, len(t) - 1)
        found = np.minimum(np.abs(t[i - 1] - q), np.abs(t[i] - q)) <= tol
        outside = (q < t[0] - tol) | (q > t[-1] + tol)
        gap = (t[i] - t[i - 1]) > 3 * period
        out &= found | outside | gap
    return out


def _ms(v: np.ndarray) -> dict:
    return {"mean": float(np.mean(v)) if len(v) else float("nan"), "std": float(np.std(v)) if len(v) else float("nan")}


def relations_metric(stamps, poses, relations: np.ndarray | str | Path, tol: float = 1e-3,
                     max_missing: float = 0.01) -> dict:
    """The four numbers of Hess et al. Table II (mean and std each) plus counts.

    Raises MetricsError when more than `max_missing` of the relations name scans the trajectory lacks
    (a relations file of another log, or stamps in another clock).
    """
    rel = read_relations(relations) if isinstance(relations, (str, Path)) else np.asarray(relations, dtype=float)
    et, er, ok = relation_errors(stamps, poses, rel, tol)
    missing = int((~ok).sum())
    lost = int((~ok & _in_gaps(stamps, rel, tol)).sum())  # scans a damaged or cut log lost: not a sign of another log
    if ok.any() and missing - lost > max_missing * len(rel) or not ok.any() and missing:
        raise MetricsError(f"{missing} of {len(rel)} relations name scan times not in the trajectory (tolerance {tol} s); "
                           f"is the relations file for this log?")
    deg = np.degrees(er)
    return {"n": int(ok.sum()), "missing": missing, "in_gaps": lost,
            "abs_trans": _ms(et), "sq_trans": _ms(et ** 2), "abs_rot_deg": _ms(deg), "sq_rot_deg2": _ms(deg ** 2),
            "max_trans": float(et.max()) if len(et) else float("nan")}


def relations_metric_split(stamps, poses, relations: np.ndarray, split_s: float = 30.0, tol: float = 1e-3) -> dict:
    """The metric on relations shorter and longer than `split_s` seconds (local accuracy vs loops)."""
    dt = relations[:, 1] - relations[:, 0]
    out = {}
    for name, sel in (("short", np.abs(dt) < split_s), ("long", np.abs(dt) >= split_s)):
        if sel.any():
            out[name] = relations_metric(stamps, poses, relations[sel], tol, max_missing=1.0)
    return out


# ---- ATE / RPE against a ground-truth trajectory (TUM), as evo computes them -------------------------------------

def associate(t_est: np.ndarray, t_ref: np.ndarray, max_diff: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (est, ref) of nearest stamps within max_diff seconds (evo's `associate_trajectories`)."""
    t_est = np.asarray(t_est, dtype=float)
    t_ref = np.asarray(t_ref, dtype=float)
    if len(t_ref) == 0 or len(t_est) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = np.argsort(t_ref)
    j = _lookup(t_ref[order], t_est, max_diff)
    ie = np.flatnonzero(j >= 0)
    return ie, order[j[ie]]


def align_se2(est_xy: np.ndarray, ref_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (2×2) and translation t minimising Σ‖R·est + t − ref‖² (Umeyama without scale)."""
    me, mr = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    C = (ref_xy - mr).T @ (est_xy - me) / len(est_xy)
    U, _, Vt = np.linalg.svd(C)
    S = np.eye(2)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[1, 1] = -1
    R = U @ S @ Vt
    return R, mr - R @ me


def ate(t_est, est, t_ref, ref, align: bool = True, max_diff: float = 0.01) -> dict:
    """Absolute trajectory error of positions after SE(2) alignment: rmse, mean, median, std, max (m)."""
    ie, ir = associate(t_est, t_ref, max_diff)
    if len(ie) < 2:
        raise MetricsError(f"only {len(ie)} poses match the ground truth in time (within {max_diff} s); "
                           f"are both in the same clock?")
    e = np.asarray(est, dtype=float)[ie, :2]
    r = np.asarray(ref, dtype=float)[ir, :2]
    if align:
        R, t = align_se2(e, r)
        e = e @ R.T + t
    d = np.hypot(*(e - r).T)
    return {"n": int(len(d)), "rmse": float(np.sqrt(np.mean(d ** 2))), "mean": float(d.mean()),
            "median": float(np.median(d)), "std": float(d.std()), "max": float(d.max())}


def rpe(t_est, est, t_ref, ref, delta: int = 1, max_diff: float = 0.01) -> dict:
    """Relative pose error over `delta` associated poses: translation (m) and rotation (deg) rmse / mean / max."""
    ie, ir = associate(t_est, t_ref, max_diff)
    if len(ie) <= delta:
        raise MetricsError(f"only {len(ie)} poses match the ground truth in time; RPE needs more than {delta}")
    e = np.asarray(est, dtype=float)[ie]
    r = np.asarray(ref, dtype=float)[ir]
    de = se2.between(e[:-delta], e[delta:])
    dr = se2.between(r[:-delta], r[delta:])
    err = se2.between(dr, de)
    t = np.hypot(err[:, 0], err[:, 1])
    a = np.degrees(np.abs(err[:, 2]))
    return {"n": int(len(t)), "delta": delta,
            "trans_rmse": float(np.sqrt(np.mean(t ** 2))), "trans_mean": float(t.mean()), "trans_max": float(t.max()),
            "rot_rmse_deg": float(np.sqrt(np.mean(a ** 2))), "rot_mean_deg": float(a.mean()), "rot_max_deg": float(a.max())}


@dataclass
class Reference:
    """A reference trajectory: poses at stamps, with a connected-component label per pose (poses in different
    components share no frame: relations-derived references can fall apart into pieces)."""

    t: np.ndarray  # (M,) seconds, sorted
    poses: np.ndarray  # (M, 3)
    comp: np.ndarray  # (M,) int

    def at(self, t, scan_t: np.ndarray | None = None, scan_poses: np.ndarray | None = None,
           max_diff: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
        """Reference poses (and components; −1 = none within max_diff s) at times t.

        With `scan_t`/`scan_poses` (a locally accurate trajectory, e.g. the front end's), the nearest
        reference pose is carried to t by that trajectory's motion: ref(r) ⊕ (ℓ(r)⁻¹ ⊕ ℓ(t)); otherwise the
        reference is interpolated.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if scan_t is None:
            i = np.clip(np.searchsorted(self.t, t), 1, len(self.t) - 1)
            j = np.where(np.abs(t - self.t[i - 1]) <= np.abs(self.t[i] - t), i - 1, i)
            ok = np.abs(self.t[j] - t) <= max_diff
            return se2.interpolate(self.t, self.poses, t), np.where(ok, self.comp[j], -1)
        j = _lookup(self.t, t, max_diff)
        ok = j >= 0
        j = np.where(ok, j, 0)
        order = np.argsort(scan_t)
        st, sp = np.asarray(scan_t, dtype=float)[order], np.asarray(scan_poses, dtype=float)[order]
        ir = _lookup(st, self.t[j], 1e-3)
        it = _lookup(st, t, 1e-3)
        ok &= (ir >= 0) & (it >= 0)
        motion = se2.between(sp[np.where(ok, ir, 0)], sp[np.where(ok, it, 0)])
        return se2.compose(self.poses[j], motion), np.where(ok, self.comp[j], -1)


def reference_from_relations(relations: np.ndarray) -> Reference:
    """The trajectory the relations were taken from, recovered by solving them as a pose graph (gtsam LM),
    one gauge per connected component. Kümmerle et al.'s relations come from one manually checked
    trajectory, so they agree to their rounding."""
    import gtsam
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    rel = np.asarray(relations, dtype=float)
    keys = np.round(rel[:, :2], 6)
    u, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(-1, 2)
    m = coo_matrix((np.ones(len(rel)), (inv[:, 0], inv[:, 1])), shape=(len(u), len(u))).tocsr()
    ncomp, comp = connected_components(m, directed=False)
    adj: dict[int, list[tuple[int, np.ndarray]]] = {}
    for (a, b), r in zip(inv, rel[:, 2:5]):
        adj.setdefault(a, []).append((b, r))
        adj.setdefault(b, []).append((a, se2.inverse(r)))
    guess = np.full((len(u), 3), np.nan)
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.005]))
    for c in range(ncomp):
        root = int(np.flatnonzero(comp == c)[0])
        guess[root] = 0.0
        graph.add(gtsam.PriorFactorPose2(root, gtsam.Pose2(0, 0, 0), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        order = breadth_first_order(m + m.T, root, directed=False, return_predecessors=False)
        for a in order:
            for b, r in adj.get(int(a), []):
                if np.isnan(guess[b, 0]):
                    guess[b] = se2.compose(guess[a], r)
    for (a, b), r in zip(inv, rel[:, 2:5]):
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), gtsam.Pose2(*r), noise))
    vals = gtsam.Values()
    for i, p in enumerate(guess):
        vals.insert(i, gtsam.Pose2(*p))
    res = gtsam.LevenbergMarquardtOptimizer(graph, vals).optimize()
    return Reference(u, gtsam.utilities.extractPose2(res), comp)


def loop_precision(loops, ref_a: np.ndarray, ref_b: np.ndarray, comp_a: np.ndarray, comp_b: np.ndarray,
                   trans_tol: float = 0.1, rot_tol_deg: float = 2.0) -> dict:
    """Share of accepted loop constraints that agree with the reference.

    `loops`: N measured relative poses a⁻¹⊕b (N×3); ref_a, ref_b the reference poses of both ends, comp_*
    their components (−1 = no reference there). A loop is correct when it differs from the reference's
    relative pose by less than trans_tol metres and rot_tol_deg degrees.
    """
    meas = np.asarray(loops, dtype=float).reshape(-1, 3)
    ok = (comp_a >= 0) & (comp_a == comp_b)
    if not ok.any():
        return {"loops": int(len(meas)), "checked": 0, "correct": 0, "precision": float("nan")}
    err = se2.between(se2.between(ref_a[ok], ref_b[ok]), meas[ok])
    et = np.hypot(err[:, 0], err[:, 1])
    er = np.degrees(np.abs(err[:, 2]))
    good = (et < trans_tol) & (er < rot_tol_deg)
    return {"loops": int(len(meas)), "checked": int(ok.sum()), "correct": int(good.sum()),
            "precision": float(good.mean()), "trans_tol": trans_tol, "rot_tol_deg": rot_tol_deg,
            "median_trans_error": float(np.median(et)), "median_rot_error_deg": float(np.median(er))}
