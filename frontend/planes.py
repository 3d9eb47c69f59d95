"""Planes found in one depth frame, and the plane operations FSPF and FSPF+ share.

`Planes` is the stage's output (thesis §3.1): the filtered points in the camera's optical frame, the plane
each belongs to, one rectified normal/offset/class per plane, and the frame's Table 5.2 statistics. Also
here: the least-squares and RANSAC plane fits, normal rectification, classification by the angle to gravity
(ground, ceiling, left, right, front, slanted) and plane merging (thesis future work, after Biswas's
polygon merging).

Plane equation convention: n·p + d = 0 with n a unit normal facing the camera, so d > 0 is the plane's
distance from the optical centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

PLANE_CLASSES = ("ground", "ceiling", "left", "right", "front", "slanted", "raised")
GROUND, CEILING, LEFT, RIGHT, FRONT, SLANTED, RAISED = range(7)


@dataclass
class FrameStats:
    """One frame's counts (thesis Table 5.2), all in pixels of the frame.

    ineligible + inliers + dropped + outliers + remaining = pixels: inliers are points of the planes kept,
    dropped the inliers of planes filtered out by class, outliers the examined points that belong to no
    plane (including planes with ≤ nMin inliers), remaining the eligible pixels never examined.
    """

    pixels: int = 0
    ineligible: int = 0
    inliers: int = 0
    dropped: int = 0
    outliers: int = 0
    remaining: int = 0
    planes: int = 0
    elapsed_ms: float = 0.0  # CPU time of the calling thread in the filter (the kernels compiled beforehand: warmup)
    windows: int = 0  # FSPF+ search windows (FSPF: neighbourhoods), for profiling
    visited: int = 0  # pixels inside those windows, consumed or not
    bent: int = 0  # FSPF+ planes rejected as strips of curved surfaces
    thin: int = 0  # FSPF+ planes rejected as too thin to define a plane
    split: int = 0  # FSPF+ planes that bridged parallel surfaces, shrunk to one of them
    grown: int = 0  # FSPF+ pixels attached to a neighbour's plane after the stop (region growing)

    def _pct(self, n: int) -> float:
        return 100.0 * n / self.pixels if self.pixels else 0.0

    @property
    def ineligible_pct(self) -> float:
        return self._pct(self.ineligible)

    @property
    def inlier_pct(self) -> float:
        return self._pct(self.inliers)

    @property
    def dropped_pct(self) -> float:
        return self._pct(self.dropped)

    @property
    def outlier_pct(self) -> float:
        return self._pct(self.outliers)

    @property
    def unexamined_pct(self) -> float:
        """The eligible pixels never examined (FSPF+ stops once fspf.analysed_fraction of them are, FSPF at n_max
        points): with the four shares above, 100 %."""
        return self._pct(self.remaining)

    @property
    def eligible(self) -> int:
        return self.pixels - self.ineligible

    COLUMNS = ("ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct", "remaining", "planes", "elapsed_ms")

    def row(self) -> dict:
        """The Table 5.2 columns (plus dropped % and plane count) as a dict."""
        return {c: getattr(self, c) for c in self.COLUMNS}


@dataclass
class Planes:
    """The planes of one depth frame (camera optical frame: x right, y down, z forward)."""

    points: np.ndarray  # N×3 float32, the filtered points
    plane: np.ndarray  # N int32, index of each point's plane
    pixels: np.ndarray  # N×2 int32, (row, col) of each point in the depth image
    normals: np.ndarray  # P×3 float64, unit normals facing the camera
    offsets: np.ndarray  # P float64, d in n·p + d = 0 (> 0: distance from the camera)
    classes: np.ndarray  # P int8, index into PLANE_CLASSES
    counts: np.ndarray  # P int64, points (pixels) per plane
    stats: FrameStats = field(default_factory=FrameStats)
    shape: tuple[int, int] = (0, 0)  # depth image rows, cols
    method: str = "fspf+"

    def __len__(self) -> int:
        return len(self.offsets)

    def point_classes(self) -> np.ndarray:
        """Class index of every point (N int8)."""
        return self.classes[self.plane] if len(self.plane) else np.zeros(0, np.int8)

    def select(self, keep_planes: np.ndarray) -> Planes:
        """The planes where `keep_planes` (bool P) holds, renumbered; stats unchanged."""
        keep_planes = np.asarray(keep_planes, bool)
        new_index = (np.cumsum(keep_planes) - 1).astype(np.int32)
        new_index[~keep_planes] = -1
        n = int(self.counts[keep_planes].sum())
        pts, plane, pix = _select_nb(self.points, self.plane, self.pixels, new_index, n)
        return Planes(pts, plane, pix, self.normals[keep_planes], self.offsets[keep_planes],
                      self.classes[keep_planes], self.counts[keep_planes], self.stats, self.shape, self.method)

    def depth_image(self) -> np.ndarray:
        """The processed depth image: each plane point's z (m) at its pixel, 0 elsewhere (float32 H×W)."""
        img = np.zeros(self.shape, np.float32)
        if len(self.points):
            img[self.pixels[:, 0], self.pixels[:, 1]] = self.points[:, 2]
        return img

    def label_image(self) -> np.ndarray:
        """Plane index + 1 at each plane point's pixel, 0 elsewhere (int32 H×W)."""
        img = np.zeros(self.shape, np.int32)
        if len(self.points):
            img[self.pixels[:, 0], self.pixels[:, 1]] = self.plane + 1
        return img

    @staticmethod
    def empty(shape: tuple[int, int] = (0, 0), stats: FrameStats | None = None, method: str = "fspf+") -> Planes:
        return Planes(np.zeros((0, 3), np.float32), np.zeros(0, np.int32), np.zeros((0, 2), np.int32),
                      np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int8), np.zeros(0, np.int64),
                      stats or FrameStats(), shape, method)


@njit(cache=True)
def _remap_nb(plane, new_index, inplace=False):
    out = plane if inplace else np.empty_like(plane)
    for i in range(len(plane)):
        out[i] = new_index[plane[i]]
    return out


@njit(cache=True)
def _select_nb(points, plane, pixels, new_index, n, inplace=False):
    """The points whose plane has new_index ≥ 0, renumbered, in one pass (in place: compacted to the front)."""
    if inplace:
        pts, pl, pix = points, plane, pixels
    else:
        pts = np.empty((n, 3), points.dtype)
        pl = np.empty(n, np.int32)
        pix = np.empty((n, 2), pixels.dtype)
    k = 0
    for i in range(len(plane)):
        j = new_index[plane[i]]
        if j >= 0 and k < n:
            pts[k, 0], pts[k, 1], pts[k, 2] = points[i, 0], points[i, 1], points[i, 2]
            pix[k, 0], pix[k, 1] = pixels[i, 0], pixels[i, 1]
            pl[k] = j
            k += 1
    return pts[:k], pl[:k], pix[:k]


# ---- fits -----------------------------------------------------------------------------------------------------------

def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit n, d) through N ≥ 3 points: the covariance's smallest eigenvector."""
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    q = p - c
    _, vecs = np.linalg.eigh(q.T @ q)
    n = vecs[:, 0]
    return n, float(-n @ c)


def refit_from_moments(count: np.ndarray, s: np.ndarray, ss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """plane_from_moments for P planes at once (count P, Σp P×3, Σppᵀ P×3×3), rectified: (normals P×3, offsets P)."""
    c = s / count[:, None]
    cov = ss / count[:, None, None] - c[:, :, None] * c[:, None, :]
    n = np.linalg.eigh(cov)[1][:, :, 0]
    d = -np.einsum("ij,ij->i", n, c)
    flip = np.where(d < 0, -1.0, 1.0)
    return n * flip[:, None], d * flip


def rectify(n: np.ndarray, d: float | np.ndarray):
    """Flip (n, d) so the normal faces the camera at the origin: d > 0 (thesis: rectified normal)."""
    n = np.asarray(n, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    s = np.where(d < 0, -1.0, 1.0)
    return n * s[..., None] if n.ndim > 1 else n * s, d * s


def ransac_plane(points: np.ndarray, epsilon: float, beta: float = 3.0, rng: np.random.Generator | None = None,
                 subset: int = 128, max_iter: int = 100) -> tuple[np.ndarray, float, np.ndarray]:
    """RANSAC plane (thesis Alg. 5): 3-point hypotheses scored on a random subset, adaptive stop, LSQ refit.

    The number of hypotheses follows Fischler & Bolles: k = (1 + β·√(1 − w³)) / w³ with w the best inlier
    fraction so far (the expected number of draws plus β standard deviations). Returns the refitted,
    rectified (n, d) and the inlier mask over all points (|n·p + d| < ε).
    """
    rng = rng or np.random.default_rng(0)
    p = np.asarray(points, dtype=np.float64)
    m = len(p)
    if m < 3:
        return np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(m, bool)
    sub = p if m <= subset else p[rng.integers(0, m, subset)]
    best_n, best_d, best = np.array([0.0, 0.0, 1.0]), 0.0, -1
    need, it, batch = float(max_iter), 0, 32
    while it < min(need, max_iter):
        k = int(min(batch, max_iter - it))
        idx = rng.integers(0, m, (k, 3))
        a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12
        it += k
        if not ok.any():
            continue
        n = n[ok] / norm[ok, None]
        d = -np.einsum("ij,ij->i", n, a[ok])
        score = (np.abs(sub @ n.T + d) < epsilon).sum(axis=0)
        j = int(np.argmax(score))
        if score[j] > best:
            best, best_n, best_d = int(score[j]), n[j], float(d[j])
            w3 = (best / len(sub)) ** 3
            need = (1.0 + beta * np.sqrt(max(0.0, 1.0 - w3))) / w3 if w3 > 0 else float(max_iter)
    inl = np.abs(p @ best_n + best_d) < epsilon
    if inl.sum() >= 3:
        n, d = fit_plane(p[inl])
        inl = np.abs(p @ n + d) < epsilon
        best_n, best_d = n, d
    n, d = rectify(best_n, best_d)
    return n, float(d), inl


# ---- classification --------------------------------------------------------------------------------------------------

def classify(normals: np.ndarray, up: np.ndarray, forward: np.ndarray, left: np.ndarray,
             slanted_min_deg: float = 3.0, slanted_max_deg: float = 80.0, offsets: np.ndarray | None = None,
             camera_height: float = float("nan"), ground_max_height: float = 0.15) -> np.ndarray:
    """Class of each camera-facing normal (P×3, optical frame) from its angle to gravity (thesis Alg. 6).

    Tilt from level below slanted_min_deg: ground (normal up) or ceiling (down); above slanted_max_deg: a
    wall, front when it faces back along the view within 45°, else left or right; between: slanted. With
    the offsets and the camera's height above the floor, an up-facing level plane higher than
    ground_max_height (a table or box top, a step) is "raised" rather than ground.
    `up, forward, left` come from `frontend.camera.camera_axes(mount)`.
    """
    n = np.atleast_2d(np.asarray(normals, dtype=np.float64))
    cu = n @ up
    tilt = np.degrees(np.arccos(np.clip(np.abs(cu), 0.0, 1.0)))
    h = n - cu[:, None] * up
    hf, hl = h @ forward, h @ left
    wall = np.where(-hf >= np.abs(hl), FRONT, np.where(hl < 0, LEFT, RIGHT))
    level_up = np.full(len(n), GROUND)
    if offsets is not None and np.isfinite(camera_height):
        height = camera_height - np.asarray(offsets, float) * cu  # the plane's height above the floor
        level_up = np.where(height > ground_max_height, RAISED, GROUND)
    out = np.where(tilt < slanted_min_deg, np.where(cu > 0, level_up, CEILING),
                   np.where(tilt > slanted_max_deg, wall, SLANTED))
    return out.astype(np.int8)


# ---- merging ---------------------------------------------------------------------------------------------------------

def moments_from_sums(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Σp P×3, Σppᵀ P×3×3) from P×9 rows (Σx, Σy, Σz, Σxx, Σxy, Σxz, Σyy, Σyz, Σzz). Plain numpy: a few planes a
    frame, and compiled it cost a fresh machine 2–4 s of numba."""
    m = np.asarray(m, np.float64)
    return m[:, :3].copy(), m[:, [3, 4, 5, 4, 6, 7, 5, 7, 8]].reshape(-1, 3, 3)


@njit(cache=True)
def _moments_nb(points, plane, P):
    """Per-plane count, Σp and Σppᵀ in one pass (float64)."""
    cnt = np.zeros(P)
    s = np.zeros((P, 3))
    ss = np.zeros((P, 3, 3))
    for i in range(len(plane)):
        k = plane[i]
        x, y, z = np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2])
        cnt[k] += 1.0
        s[k, 0] += x
        s[k, 1] += y
        s[k, 2] += z
        ss[k, 0, 0] += x * x
        ss[k, 0, 1] += x * y
        ss[k, 0, 2] += x * z
        ss[k, 1, 1] += y * y
        ss[k, 1, 2] += y * z
        ss[k, 2, 2] += z * z
    for k in range(P):
        ss[k, 1, 0] = ss[k, 0, 1]
        ss[k, 2, 0] = ss[k, 0, 2]
        ss[k, 2, 1] = ss[k, 1, 2]
    return cnt, s, ss


@njit(cache=True)
def _plane_rms_nb(n, s, ss, cov):
    """The RMS distance of n points (Σp s, Σppᵀ ss) from their least-squares plane (cov: scratch 3×3)."""
    for a in range(3):
        for b in range(3):
            cov[a, b] = ss[a, b] / n - (s[a] / n) * (s[b] / n)
    return np.sqrt(max(np.linalg.eigh(cov)[0][0], 0.0))


@njit(cache=True)
def _merge_nb(normals, offsets, cnt, s, ss, order, cos_max, offset_m, rms_step):
    """Greedy merge in `order` (largest first): returns each plane's group and the groups' refitted (n, d).

    Written element by element: numba compiles array slices, np.outer and its argsort with shape checks and
    their error messages, ~8 s of a fresh machine's first run (make demo), for the same arithmetic."""
    P = len(cnt)
    group = np.full(P, -1, np.int64)
    g_cnt = np.zeros(P)
    g_s = np.zeros((P, 3))
    g_ss = np.zeros((P, 3, 3))
    g_n = np.zeros((P, 3))
    g_d = np.zeros(P)
    g_rms0 = np.zeros(P)  # the residual RMS of each group's first (largest) patch: merging may not raise it by more
    c = np.empty(3)
    cov = np.empty((3, 3))
    G = 0
    for i in order:
        if cnt[i] == 0:
            continue
        c0, c1, c2 = s[i, 0] / cnt[i], s[i, 1] / cnt[i], s[i, 2] / cnt[i]
        n0, n1, n2 = normals[i, 0], normals[i, 1], normals[i, 2]
        hit = -1
        rms_i = -1.0
        for g in range(G):
            if g_n[g, 0] * n0 + g_n[g, 1] * n1 + g_n[g, 2] * n2 < cos_max:
                continue
            e1 = abs(g_n[g, 0] * c0 + g_n[g, 1] * c1 + g_n[g, 2] * c2 + g_d[g])
            if e1 >= offset_m:
                continue
            # one surface: the merged plane's residual RMS hardly exceeds its parts' (parallel surfaces a few cm
            # apart would raise it by their separation; the far centroid's distance to the patch's own plane
            # is no test: a small patch's normal is uncertain by degrees)
            if rms_i < 0:
                rms_i = _plane_rms_nb(cnt[i], s[i], ss[i], cov)
            n_m = g_cnt[g] + cnt[i]
            for a in range(3):
                c[a] = (g_s[g, a] + s[i, a]) / n_m
            for a in range(3):
                for b in range(3):
                    cov[a, b] = (g_ss[g, a, b] + ss[i, a, b]) / n_m - c[a] * c[b]
            rms_m = np.sqrt(max(np.linalg.eigh(cov)[0][0], 0.0))
            if rms_m <= max(g_rms0[g], rms_i) + rms_step:
                hit = g
                break
        g = G if hit < 0 else hit
        group[i] = g
        if hit < 0:
            g_rms0[g] = rms_i if rms_i >= 0 else _plane_rms_nb(cnt[i], s[i], ss[i], cov)
            g_cnt[g] = cnt[i]
            for a in range(3):
                g_s[g, a] = s[i, a]
                g_n[g, a] = normals[i, a]
                for b in range(3):
                    g_ss[g, a, b] = ss[i, a, b]
            g_d[g] = offsets[i]
            G += 1
            continue
        g_cnt[g] += cnt[i]
        for a in range(3):
            g_s[g, a] += s[i, a]
            for b in range(3):
                g_ss[g, a, b] += ss[i, a, b]
        for a in range(3):
            c[a] = g_s[g, a] / g_cnt[g]
        for a in range(3):
            for b in range(3):
                cov[a, b] = g_ss[g, a, b] / g_cnt[g] - c[a] * c[b]
        w, v = np.linalg.eigh(cov)
        nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
        d = -(nx * c[0] + ny * c[1] + nz * c[2])
        if d < 0:
            nx, ny, nz, d = -nx, -ny, -nz, -d
        g_n[g, 0], g_n[g, 1], g_n[g, 2] = nx, ny, nz
        g_d[g] = d
    return group, g_n[:G].copy(), g_d[:G].copy()


def merge_planes(planes: Planes, angle_deg: float, offset_m: float, classify_fn=None,
                 drop_classes: tuple[int, ...] = (), moments: tuple | None = None, inplace: bool = False,
                 rms_step: float | None = None) -> Planes:
    """Merge coplanar patches (thesis future work; Biswas's polygon merging): one refitted plane each.

    Greedy, largest patch first: a patch joins the first merged plane whose normal is within angle_deg, whose
    plane passes within offset_m of the patch's centroid, and which stays one surface with it: the residual RMS
    of the merged points about their plane exceeds the patch's and the group's first (largest) patch's by at
    most rms_step (default offset_m / 50; FSPF+ passes ε/20). Two parallel surfaces, a table and a box top,
    raise it by about their separation; the bound is the first patch's, so that small steps cannot add up.
    The merged plane is refitted by least squares from the accumulated moments (Σp, Σppᵀ) and rectified. `classify_fn(normals, offsets)`
    gives the merged planes' classes (default: the class of their largest patch); planes whose class is in
    drop_classes are dropped. `moments` (count P, Σp P×3, Σppᵀ P×3×3) saves a pass over the points;
    `inplace` lets it reuse the input's point arrays (the input must not be used afterwards).
    """
    P = len(planes)
    if P <= 1:
        return planes
    cnt, s, ss = moments if moments is not None else _moments_nb(planes.points, planes.plane, P)
    cnt = np.asarray(cnt, np.float64)
    group, normals, offsets = _merge_nb(np.ascontiguousarray(planes.normals, dtype=np.float64),
                                        np.ascontiguousarray(planes.offsets, dtype=np.float64), cnt, s, ss,
                                        np.argsort(-cnt, kind="stable"), float(np.cos(np.radians(angle_deg))),
                                        float(offset_m), float(offset_m) / 50.0 if rms_step is None else float(rms_step))
    G = len(offsets)
    if G == P:
        return planes
    if classify_fn is not None:
        classes = np.asarray(classify_fn(normals, offsets), np.int8)
    else:
        order = np.argsort(-np.asarray(cnt), kind="stable")
        classes = np.zeros(G, np.int8)
        classes[group[order][::-1]] = planes.classes[order][::-1]  # the largest patch writes last
    counts = np.bincount(group, weights=planes.counts, minlength=G).astype(np.int64)
    dropped = np.zeros(len(PLANE_CLASSES), bool)
    dropped[list(drop_classes)] = True
    keep = ~dropped[classes]
    stats = replace(planes.stats)
    if keep.all():
        new_plane = _remap_nb(planes.plane, group.astype(np.int32), inplace)
        merged = Planes(planes.points, new_plane, planes.pixels, normals, offsets, classes, counts, stats,
                        planes.shape, planes.method)
    else:  # a merged plane turned out to be of a dropped class: renumber and drop in one pass
        lost = int(counts[~keep].sum())
        new_index = (np.cumsum(keep) - 1).astype(np.int32)
        new_index[~keep] = -1
        pts, pl, pix = _select_nb(planes.points, planes.plane, planes.pixels, new_index[group].astype(np.int32),
                                  int(counts[keep].sum()), inplace)
        stats.inliers -= lost
        stats.dropped += lost
        merged = Planes(pts, pl, pix, normals[keep], offsets[keep], classes[keep], counts[keep], stats,
                        planes.shape, planes.method)
    merged.stats.planes = len(merged)
    return merged
