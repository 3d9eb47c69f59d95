"""Scoring planes against a renderer's ground truth (surface id per pixel, true plane per surface)."""

from __future__ import annotations

import numpy as np

from kosmap.frontend.camera import rays
from kosmap.frontend.planes import PLANE_CLASSES, Planes

WALL_CLASSES = {PLANE_CLASSES.index(c) for c in ("left", "right", "front")}


def camera_plane(plane_w: np.ndarray, world_from_cam: np.ndarray) -> np.ndarray:
    """A world plane (a, b, c, d) in the camera frame, given the 4×4 world ← camera transform."""
    R, t = world_from_cam[:3, :3], world_from_cam[:3, 3]
    n = plane_w[:3]
    return np.append(R.T @ n, n @ t + plane_w[3])


def score(planes: Planes, sid: np.ndarray, truth: dict[int, tuple[str, np.ndarray]], world_from_cam: np.ndarray,
          camera, sigma, with_incidence: bool = False) -> dict:
    """Accuracy of `planes` against the truth: {surface id: (class, world plane)}; sigma(z) is the noise model.

    - on_own_surface: fraction of points whose pixel shows a planar surface, within 3σ of it;
    - on_surface (stricter): within 3σ (along the ray) of the true plane of their plane's majority surface
      (a plane that straddles two surfaces loses the minority's points);
    - normal_err_deg: per plane, angle to its majority surface's normal (median over planes, and all);
    - class_ok: fraction of points on known-class surfaces whose plane's class matches (per class in
      class_ok_by).
    sigma(z) (or sigma(z, |cos incidence|) when with_incidence) is the noise model's axial σ.
    """
    out = {"points": len(planes.points), "planes": len(planes)}
    if len(planes.points) == 0:
        return out | {"on_surface": 0.0, "median_normal_err_deg": 180.0, "class_ok": 0.0}
    ray = rays(camera)
    r, c = planes.pixels[:, 0], planes.pixels[:, 1]
    psid = sid[r, c]
    cam_planes = {k: camera_plane(np.asarray(p, float), world_from_cam) for k, (_, p) in truth.items()}
    majority = np.zeros(len(planes), np.int64)
    errs = np.zeros(len(planes))
    for k in range(len(planes)):
        ids = psid[planes.plane == k]
        ids = ids[np.isin(ids, list(cam_planes))]  # planar surfaces only (no flying pixels, no cylinders)
        if len(ids) == 0:
            majority[k], errs[k] = 0, 90.0
            continue
        majority[k] = np.bincount(ids).argmax()
        n_true = cam_planes[majority[k]][:3]
        n_true = n_true / np.linalg.norm(n_true)
        errs[k] = np.degrees(np.arccos(min(1.0, abs(float(planes.normals[k] @ n_true)))))
    good = np.zeros(len(planes.points), bool)
    z = planes.points[:, 2].astype(float)

    def within_3_sigma(sel: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Whether the selected points' depths lie within 3σ of where their pixels' rays meet plane p."""
        rr = ray[r[sel], c[sel]]
        z_hit = -p[3] / (rr @ p[:3])
        if with_incidence:
            cos_inc = np.abs(rr @ p[:3]) / (np.linalg.norm(rr, axis=1) * np.linalg.norm(p[:3]))
            s = sigma(z_hit, cos_inc)
        else:
            s = sigma(z_hit)
        return np.abs(z[sel] - z_hit) <= 3 * s

    for k in range(len(planes)):
        if majority[k] == 0:
            continue
        sel = planes.plane == k
        good[sel] = within_3_sigma(sel, cam_planes[majority[k]])
    # literal: each point's own pixel shows a planar surface and the point is within 3σ of it
    own = np.zeros(len(z), bool)
    for k in np.unique(psid):
        if k not in cam_planes:
            continue
        sel = psid == k
        own[sel] = within_3_sigma(sel, cam_planes[k])
    out["on_own_surface"] = float(own.mean())
    pclass = planes.classes[planes.plane]
    maj_cls = np.array([truth[m][0] if m in truth else "" for m in majority])[planes.plane]
    ok = np.zeros(len(z), bool)
    known = np.zeros(len(z), bool)
    by: dict[str, tuple[float, int]] = {}
    for name, allowed in (("ground", {0}), ("ceiling", {1}), ("wall", WALL_CLASSES), ("slanted", {5})):
        sel = maj_cls == name
        known |= sel
        hit = sel & np.isin(pclass, list(allowed))
        ok |= hit
        if sel.any():
            by[name] = (float(hit.sum() / sel.sum()), int(sel.sum()))
    return out | {"on_surface": float(good.mean()), "median_normal_err_deg": float(np.median(errs)),
                  "normal_errs_deg": errs, "majority": majority, "class_ok_by": by,
                  "class_ok": float(ok[known].mean()) if known.any() else 1.0}


def recovered(planes: Planes, sid: np.ndarray, eligible: np.ndarray, surface_ids) -> float:
    """Fraction of eligible pixels of the given surfaces that are plane points."""
    want = np.isin(sid, list(surface_ids)) & eligible
    got = np.zeros(sid.shape, bool)
    got[planes.pixels[:, 0], planes.pixels[:, 1]] = True
    return float((got & want).sum() / max(1, want.sum()))
