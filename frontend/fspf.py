"""FSPF (Biswas & Veloso) and FSPF+ (thesis Alg. 1, 3–6): sampled plane filtering of depth images.

Both take a depth image in metres, the pinhole camera and an explicit seed, and return `Planes`
(frontend/planes.py). The inner loops run compiled with numba (docs/dependencies.md measured numpy-only FSPF+ at
18–20 ms per 512×424 frame against ~3 ms compiled); the benchmark's numpy versions of the same algorithms are
tools/fspf_numpy.py.

FSPF+ (thesis Alg. 3): p0 a random eligible, unconsumed pixel; p1, p2 eligible within Ω of it; the search
window W = fx·Δ/z̄, H = fy·Δ/z̄ around p0 (the projection of the world size Δ at their mean depth z̄;
docs/design.md), clipped at the border; its eligible pixels become 3D points and are consumed; RANSAC (ε, β;
Alg. 5) finds the plane, refitted by least squares; the normal is rectified to face the camera and
classified (Alg. 6); planes of dropped classes and planes with ≤ nMin inliers are discarded; the loop stops
when fewer than (1 − analysed fraction) of the eligible pixels are unconsumed. RANSAC scores its hypotheses
on a random subset of the window (docs/dependencies.md), refits the winner on the subset's inliers, and the final plane
is the least-squares fit of all its inliers (their moments, accumulated in the one pass that writes them).

Our additions, each with a switch in FspfConfig: after the first plane, RANSAC runs again on the window's
remaining points (`planes_per_window`, 1 = the thesis), so a window that straddles a wall and the floor
keeps both; a plane's noise tail (ε … `tail_eps`·ε) seeds no further plane; planes whose inliers are a
thin strip (`min_width`) or bend like a strip of a cylinder (`bend_max`: people, bins, pillars) are
rejected; a plane whose inliers are not one surface (`coherence`: tested on a sample before it takes them, the
surfaces' own normal from the image's local normals is tilted against the plane's, as when a tilted plane cuts a
strip of a table and of the box tops on it, or their spread about it exceeds the sensor noise measured in the same
pixels) shrinks to one of the surfaces (the most populated layer along their normal, or its strongest sub-plane)
before it takes its inliers; after the stop, the unexamined pixels next to
a plane and within ε of it join it (`grow`, region growing on the organised image); coplanar planes are
merged when the merged plane stays one surface (frontend/planes.py) and each patch's centroid lies within ε of it.

Coverage against time: the thesis's stop (nRequired = analysed_fraction of the eligible pixels) leaves the
rest unexamined; windows land at random, so which 10 % that is varies by seed (the labelled mOSD table:
81–100 % of it on its plane at 0.90, 87–100 % at 0.99). Growing attaches those pixels at ~25 ns each, less
than a window's RANSAC costs, so the default keeps 0.90 and grows (100 % of the table at every seed); a
higher analysed_fraction only buys planes in regions no plane touches (small objects), at the windows' cost.
Measured: tests/tools/test_planes_real.py, tests/frontend/test_fspf_tabletop.py, tools/bench_planes.py.
Simulated acceptance numbers: tests/frontend/test_fspf_sim.py; speed: tools/bench_planes.py.

FSPF (Biswas & Veloso 2012, thesis Alg. 1): random d0, d1, d2 within η; a plane through their points; l
local samples in the window of world size S around d0; accepted when the inlier fraction reaches α_in; stop
at n_max filtered points or k_max neighbourhoods. Its normal is refitted by least squares on the inliers.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from kosmap.frontend.camera import DepthConfig, camera_axes
from kosmap.frontend.fspf_biswas import Params as BiswasParams, fspf_kernel
from kosmap.frontend.fspf_kernels import classify_many, rng_state
from kosmap.frontend.fspf_plus import Params, fspf_plus_kernel
from kosmap.frontend.params import StageConfig, param
from kosmap.frontend.planes import PLANE_CLASSES, FrameStats, Planes, merge_planes, moments_from_sums
from kosmap.frontend.records import CameraModel, Transform

__all__ = ["FspfConfig", "PLANE_CLASSES", "filter_planes", "fspf_plus", "fspf", "frame_seed", "warmup"]


@dataclass
class FspfConfig(StageConfig):
    """[fspf]: FSPF+ defaults from the thesis's Table 5.4 (real-time configuration); FSPF from Biswas's config."""

    section = "fspf"
    method: str = param("fspf+", choices=("fspf+", "fspf"), doc="FSPF+ (thesis) or FSPF (Biswas, baseline)")
    n_min: int = param(40, lo=3, doc="FSPF+: planes with this many inliers or fewer are dropped (nMin)")
    omega_px: int = param(60, lo=2, doc="FSPF+: p1, p2 are drawn within this many pixels of p0 (Ω)", unit="px")
    delta_m: float = param(0.5, lo=0.0, lo_open=True, doc="world size of the search window (Δ; FSPF's S)", unit="m")
    epsilon_m: float = param(0.02, lo=0.0, lo_open=True, doc="FSPF+: RANSAC inlier distance (ε)", unit="m")
    beta: float = param(3.0, lo=0.0, doc="FSPF+: RANSAC stopping factor (β: standard deviations of the draw count)")
    analysed_fraction: float = param(0.90, lo=0.0, hi=1.0, lo_open=True,
                                     doc="FSPF+: stop when this fraction of eligible pixels is consumed (nRequired); with grow the rest "
                                     "next to a plane still joins it, so higher values only add planes where none was found, at the windows' cost")
    ransac_subset: int = param(128, lo=3, doc="FSPF+: hypotheses are scored on this many random window points")
    ransac_max_iter: int = param(100, lo=1, doc="FSPF+: at most this many RANSAC hypotheses per plane")
    planes_per_window: int = param(3, lo=1, doc="FSPF+: planes sought per window (1 = the thesis; more keeps corners)")
    extra_min_fraction: float = param(0.0, lo=0.0, hi=1.0, doc="FSPF+: a further plane in a window is sought only "
                                      "while at least this fraction of the window's points is left (0.1 is a little "
                                      "faster and cleaner, but loses small objects on big surfaces, e.g. a box on a table)")
    bend_max: float = param(1.0, lo=0.0, doc="FSPF+: reject a plane whose inliers bend by more than this many ε "
                            "(a quadratic explaining > 50 % of their residuals: strips of people, bins, pillars); 0 = off")
    min_width: float = param(0.5, lo=0.0, doc="FSPF+: reject a plane whose inliers spread less than this many ε "
                             "(std. dev.) across their second direction: a thin strip fits many planes; 0 = off")
    coherence: bool = param(True, doc="FSPF+: a plane tilted against the surfaces under its inliers (their local normals) "
                            "or spread over ±ε instead of crowding around it bridges parallel surfaces (a table and the "
                            "box tops on it): it shrinks to the strongest one")
    grow: bool = param(True, doc="FSPF+: after the stop (analysed_fraction), unexamined pixels within ε of a 4-neighbour's "
                       "plane join it (region growing): the coverage of a full pass for a fraction of its time")
    tail_eps: float = param(2.0, lo=1.0, doc="FSPF+: a plane's points from ε to this many ε are its noise tail: "
                            "outliers that seed no further plane in the window (1 = off)")
    fspf_max_points: int = param(2000, lo=1, doc="FSPF: stop after this many filtered points (n_max)")
    fspf_max_neighborhoods: int = param(20000, lo=1, doc="FSPF: stop after this many neighbourhoods (k_max)")
    fspf_local_samples: int = param(80, lo=3, doc="FSPF: local samples per neighbourhood (l; Biswas 50–100)")
    fspf_window_px: int = param(60, lo=2, doc="FSPF: d1, d2 are drawn within ±window/2 of d0 (η)", unit="px")
    fspf_error_m: float = param(0.03, lo=0.0, lo_open=True, doc="FSPF: plane inlier distance (ε)", unit="m")
    fspf_min_inlier_fraction: float = param(0.8, lo=0.0, hi=1.0, lo_open=True, doc="FSPF: accept at this inlier fraction (α_in)")
    slanted_min_deg: float = param(3.0, lo=0.0, hi=90.0, doc="tilted less than this from level: ground or ceiling "
                                   "(a 1:12 ramp is 4.8°)", unit="deg")
    slanted_max_deg: float = param(80.0, lo=0.0, hi=90.0, doc="tilted more than this: a wall; between: slanted", unit="deg")
    ground_max_height: float = param(0.15, doc="an up-facing level plane higher than this above the floor (from the "
                                     "mount) is 'raised' (a table top), not ground", unit="m")
    merge: bool = param(True, doc="merge coplanar patches into one refitted plane")
    merge_angle_deg: float = param(5.0, lo=0.0, hi=90.0, doc="merge: normals agree within this angle", unit="deg")
    merge_offset_m: float = param(0.05, lo=0.0, doc="merge: the patch's centroid within this distance of the merged plane, "
                                    "and within ε (which must also stay one surface: its residual RMS grows by ε/20 at most)", unit="m")
    drop_classes: list = param(["ground", "ceiling"], choices=PLANE_CLASSES, doc="plane classes filtered out")
    seed: int = param(0, lo=0, doc="random seed (per frame, the frame index is added)")

    def __post_init__(self) -> None:
        super().__post_init__()
        from kosmap.frontend.errors import ConfigError

        if self.slanted_max_deg < self.slanted_min_deg:
            raise ConfigError(f"config [fspf] slanted_max_deg = {self.slanted_max_deg} must be ≥ slanted_min_deg = {self.slanted_min_deg}")


def frame_seed(cfg: FspfConfig, index: int) -> int:
    """The seed of frame `index` (the config's seed plus the index)."""
    return int(cfg.seed) + int(index)


# The kernels below use numba's numpy error model: a division is a plain division (inf/NaN on a zero divisor, as in
# numpy) instead of a test that raises ZeroDivisionError and ends the build. The same planes, bit for bit, on 300
# frames of the office log; 4–18 % less FSPF+ time in three alternating runs on this machine.


# ---- the public entry points ---------------------------------------------------------------------------------------------

def _prepare(depth_m, cam: CameraModel):
    depth = np.ascontiguousarray(depth_m, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth image must be 2-D, got shape {depth.shape}")
    if depth.shape[0] >= 1 << 15 or depth.shape[1] >= 1 << 16:  # FSPF+ packs a pixel as row << 16 | column
        raise ValueError(f"depth image of {depth.shape[1]}×{depth.shape[0]} pixels: at most 65535 columns and 32767 rows")
    if (cam.height, cam.width) != depth.shape:
        raise ValueError(f"camera is {cam.width}×{cam.height} but the depth image is {depth.shape[1]}×{depth.shape[0]}; "
                         "use frontend.camera.camera_for")
    return depth


_AXES: dict[bytes | None, tuple] = {}


def _axes(mount: Transform | None) -> tuple:
    """camera_axes, remembered per mount rotation (a frame's mount arrives as a new object in a worker; the
    numpy of camera_axes cost ~0.1 ms a frame)."""
    key = None if mount is None else np.asarray(mount.rotation, np.float64).tobytes()
    axes = _AXES.get(key)
    if axes is None:
        if len(_AXES) > 64:
            _AXES.clear()
        axes = _AXES[key] = camera_axes(mount)
    return axes


class _Classes:
    """Plane classes for one camera: gravity axes and height from the mount, bounds from the config."""

    def __init__(self, cfg: FspfConfig, mount: Transform | None) -> None:
        self.up, self.fwd, self.left = _axes(mount)
        self.cam_h = float(mount.translation[2]) if mount is not None else float("nan")
        self.cfg = cfg

    def __call__(self, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """planes.classify, compiled (the same rules: tests/frontend/test_fspf.py checks they agree)."""
        return classify_many(np.ascontiguousarray(normals, np.float64), np.ascontiguousarray(offsets, np.float64),
                                 *self.args())

    def args(self) -> tuple:
        c = self.cfg
        return (self.up, self.fwd, self.left, c.slanted_min_deg, c.slanted_max_deg, self.cam_h, c.ground_max_height)


_WORK = threading.local()
_DEFAULT_DEPTH = DepthConfig()


def _workspace(npx: int, p_cap: int) -> dict:
    """Buffers the FSPF+ kernel reuses from frame to frame (per thread): fresh memory costs a page fault per
    4 KiB on first touch, which on a virtual machine was a third of a frame's time."""
    ws = getattr(_WORK, "ws", None)
    if ws is None or ws["npx"] < npx or ws["p_cap"] < p_cap:
        ws = {"npx": npx, "p_cap": p_cap, "st": np.empty(npx, np.uint8), "cand": np.empty(npx, np.int32),
              "win": np.empty(npx, np.int32), "stack": np.empty(npx, np.int32), "lbl": np.empty(npx, np.int32),
              "out_pix": np.empty((npx, 2), np.int32), "out_pts": np.empty((npx, 3), np.float32),
              "out_plane": np.empty(npx, np.int32), "pl_n": np.empty((p_cap, 3)), "pl_d": np.empty(p_cap),
              "pl_cls": np.empty(p_cap, np.int8), "pl_cnt": np.empty(p_cap, np.int64), "pl_mom": np.empty((p_cap, 9))}
        _WORK.ws = ws
    return ws


def _frame_start(depth_m, cam: CameraModel, cfg: FspfConfig | None, depth_cfg: DepthConfig | None,
                 mount: Transform | None, seed: int | None) -> tuple:
    """What every plane filter starts a frame with: the thread's CPU clock, the configs (defaults for None), the
    depth image checked against the camera, the plane classes for the mount, and the seed (the config's for None).
    Returns (t0, cfg, depth_cfg, depth, classes_of, seed)."""
    t0 = time.thread_time()
    cfg = cfg or FspfConfig()
    return (t0, cfg, depth_cfg or _DEFAULT_DEPTH, _prepare(depth_m, cam), _Classes(cfg, mount),
            cfg.seed if seed is None else seed)


def _finish(planes: Planes, cfg: FspfConfig, classes_of: _Classes, t0: float, moments=None) -> Planes:
    if cfg.merge and len(planes) > 1:
        drop = tuple(PLANE_CLASSES.index(c) for c in cfg.drop_classes)
        # merged planes stay one surface: their residual RMS may grow by ε/20 at most, and a patch's centroid lies
        # within ε of the merged plane (farther, its points would leave the plane's inlier band: another surface,
        # a box top on a table, which the RMS bound misses when the patch is small beside the table)
        eps = cfg.fspf_error_m if planes.method == "fspf" else cfg.epsilon_m
        planes = merge_planes(planes, cfg.merge_angle_deg, min(cfg.merge_offset_m, eps), classes_of, drop, moments,
                              inplace=True, rms_step=eps / 20.0)
    planes.stats.planes = len(planes)
    planes.stats.elapsed_ms = (time.thread_time() - t0) * 1e3  # this thread's CPU time: the algorithm's own
    return planes


def _drop_mask(cfg: FspfConfig) -> np.ndarray:
    return np.array([c in cfg.drop_classes for c in PLANE_CLASSES], dtype=np.bool_)


def fspf_plus(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None, depth_cfg: DepthConfig | None = None,
              mount: Transform | None = None, seed: int | None = None, copy: bool = True) -> Planes:
    """FSPF+ (thesis Alg. 3, 5, 6) on one depth image (H×W metres; 0/NaN invalid). Same seed, same result.

    `mount` (base_link ← optical, frontend.camera.camera_mount) gives gravity for the classes; None = level.
    `copy=False` returns the points, plane indices and pixels as views of this thread's scratch buffers, valid
    only until its next call: for a caller that uses them at once (kosframe.py; copying them cost ~0.5 ms a frame).
    """
    t0, cfg, dcfg, depth, classes_of, seed = _frame_start(depth_m, cam, cfg, depth_cfg, mount, seed)
    H, W = depth.shape
    ws = _workspace(H * W, H * W // (cfg.n_min + 1) + 1)
    out_pix, out_pts, out_plane = ws["out_pix"], ws["out_pts"], ws["out_plane"]
    pl_n, pl_d, pl_cls, pl_cnt, pl_mom = ws["pl_n"], ws["pl_d"], ws["pl_cls"], ws["pl_cnt"], ws["pl_mom"]
    stats = np.zeros(12, np.int64)
    prm = Params(float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), float(dcfg.min_depth),
                 float(dcfg.max_depth), int(cfg.n_min), int(cfg.omega_px), float(cfg.delta_m), float(cfg.epsilon_m),
                 float(cfg.beta), float(cfg.analysed_fraction), int(cfg.ransac_subset), int(cfg.ransac_max_iter),
                 int(cfg.planes_per_window), float(cfg.extra_min_fraction), float(cfg.bend_max), float(cfg.min_width),
                 float(cfg.tail_eps), bool(cfg.coherence), bool(cfg.grow), float(cfg.slanted_min_deg),
                 float(cfg.slanted_max_deg), float(classes_of.cam_h), float(cfg.ground_max_height))
    bufs = (ws["st"], ws["cand"], ws["win"], ws["stack"], ws["lbl"])
    out = (out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls, pl_cnt, pl_mom)
    n, p = fspf_plus_kernel(depth, prm, (classes_of.up, classes_of.fwd, classes_of.left), _drop_mask(cfg),
                         rng_state(seed), bufs, out, stats)
    pts, plane, pix = (out_pts[:n].copy(), out_plane[:n].copy(), out_pix[:n].copy()) if copy else \
        (out_pts[:n], out_plane[:n], out_pix[:n])
    planes = Planes(pts, plane, pix, pl_n[:p].copy(), pl_d[:p].copy(),
                    pl_cls[:p].copy(), pl_cnt[:p].copy(), FrameStats(*(int(s) for s in stats[:6])), (H, W), "fspf+")
    planes.stats.windows, planes.stats.visited = int(stats[6]), int(stats[7])
    planes.stats.bent, planes.stats.thin = int(stats[8]), int(stats[9])
    planes.stats.split, planes.stats.grown = int(stats[10]), int(stats[11])
    s1, s2 = moments_from_sums(pl_mom[:p])
    return _finish(planes, cfg, classes_of, t0, (planes.counts.astype(np.float64), s1, s2))


def fspf(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None, depth_cfg: DepthConfig | None = None,
         mount: Transform | None = None, seed: int | None = None) -> Planes:
    """FSPF (Biswas & Veloso; thesis Alg. 1), the baseline, with the same classes, dropping and merging."""
    t0, cfg, dcfg, depth, classes_of, seed = _frame_start(depth_m, cam, cfg, depth_cfg, mount, seed)
    H, W = depth.shape
    l = cfg.fspf_local_samples
    n_cap = cfg.fspf_max_points + l
    p_cap = cfg.fspf_max_points + 1
    out_pix = np.empty((n_cap, 2), np.int32)
    out_pts = np.empty((n_cap, 3), np.float32)
    out_plane = np.empty(n_cap, np.int32)
    pl_n, pl_d = np.empty((p_cap, 3)), np.empty(p_cap)
    pl_cls, pl_cnt = np.empty(p_cap, np.int8), np.empty(p_cap, np.int64)
    stats = np.zeros(6, np.int64)
    prm = BiswasParams(float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), float(dcfg.min_depth),
                       float(dcfg.max_depth), int(cfg.fspf_max_points), int(cfg.fspf_max_neighborhoods), int(l),
                       int(cfg.fspf_window_px), float(cfg.delta_m), float(cfg.fspf_error_m),
                       float(cfg.fspf_min_inlier_fraction), float(cfg.slanted_min_deg), float(cfg.slanted_max_deg),
                       float(classes_of.cam_h), float(cfg.ground_max_height))
    out = (out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls, pl_cnt)
    n, p = fspf_kernel(depth, prm, (classes_of.up, classes_of.fwd, classes_of.left), _drop_mask(cfg), rng_state(seed),
                       _workspace(H * W, 1)["st"], out, stats)
    planes = Planes(out_pts[:n].copy(), out_plane[:n].copy(), out_pix[:n].copy(), pl_n[:p].copy(), pl_d[:p].copy(),
                    pl_cls[:p].copy(), pl_cnt[:p].copy(), FrameStats(*(int(s) for s in stats)), (H, W), "fspf")
    return _finish(planes, cfg, classes_of, t0)


def framed(kernel, depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None,
           depth_cfg: DepthConfig | None = None, mount: Transform | None = None, seed: int | None = None) -> Planes:
    """A plane filter `kernel(depth, cam, cfg, depth_cfg, classes_of, drop, rng)` framed as fspf_plus and fspf frame
    theirs: the depth checked, the classes, dropping and merging, the time. For the numpy reference versions of
    the benchmark (tools/fspf_numpy.py)."""
    t0, cfg, dcfg, depth, classes_of, seed = _frame_start(depth_m, cam, cfg, depth_cfg, mount, seed)
    planes = kernel(depth, cam, cfg, dcfg, classes_of, _drop_mask(cfg), np.random.default_rng(seed))
    return _finish(planes, cfg, classes_of, t0)


def filter_planes(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None,
                  depth_cfg: DepthConfig | None = None, mount: Transform | None = None, seed: int | None = None,
                  copy: bool = True) -> Planes:
    """FSPF+ or FSPF as `cfg.method` says (`copy`: see fspf_plus; FSPF's arrays are its own)."""
    cfg = cfg or FspfConfig()
    if cfg.method == "fspf":
        return fspf(depth_m, cam, cfg, depth_cfg, mount, seed)
    return fspf_plus(depth_m, cam, cfg, depth_cfg, mount, seed, copy=copy)


def warmup(method: str | None = None, shape: tuple[int, int] | None = None) -> None:
    """Compile (or load from numba's cache) the kernel of `method` ("fspf+" or "fspf"; None: both) on a tiny image:
    on a fresh machine FSPF's costs 5 s that a build with FSPF+ never needs. With `shape` (rows, cols), FSPF+'s
    buffers for frames of that size are made too, so that the first frame's time is the algorithm's alone."""
    if shape is not None and method in (None, "fspf+"):
        h, w = int(shape[0]), int(shape[1])
        fspf_plus(np.zeros((h, w), np.float32), CameraModel.from_fov(w, h, np.radians(70.0), np.radians(60.0)))
    cam = CameraModel.from_fov(32, 24, np.radians(70.0), np.radians(60.0))
    d = np.full((24, 32), 2.0, np.float32)
    d[:, 16:] = 2.0 + 0.05 * np.arange(16)  # a fold: two planes, so merging compiles too
    if method in (None, "fspf+"):
        fspf_plus(d, cam, FspfConfig(n_min=3, delta_m=0.2))
    if method in (None, "fspf"):
        fspf(d, cam, FspfConfig(fspf_max_neighborhoods=10))
