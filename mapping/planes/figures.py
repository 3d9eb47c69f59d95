"""Figures like the thesis's Fig. 5.2: the filtered points seen from the front and from the top,
coloured by depth (red near → purple far) and by plane class."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kosmap.frontend.planes import PLANE_CLASSES, Planes

CLASS_COLOURS = {"ground": "#8c564b", "ceiling": "#7f7f7f", "left": "#1f77b4", "right": "#2ca02c",
                 "front": "#d62728", "slanted": "#ff7f0e", "raised": "#9467bd"}


def plane_figure(planes: Planes, path: str | Path, title: str = "", depth_range: tuple[float, float] = (0.5, 4.5),
                 max_points: int = 60000, seed: int = 0) -> Path:
    """Write a 2×2 PNG: front view (x, −y) and top view (x, z), by depth and by class."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    p = planes.points
    cls = planes.point_classes()
    if len(p) > max_points:
        sel = np.random.default_rng(seed).choice(len(p), max_points, replace=False)
        p, cls = p[sel], cls[sel]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8.5), constrained_layout=True)
    colours = np.array([CLASS_COLOURS[c] for c in PLANE_CLASSES])
    views = (("front view", 0, 1, "x (m, right)", "−y (m, up)", -1), ("top view", 0, 2, "x (m, right)", "z (m, forward)", 1))
    sc = None
    for col, (name, a, b, xl, yl, sgn) in enumerate(views):
        for row in range(2):
            axis = ax[row, col]
            if len(p):
                if row == 0:
                    sc = axis.scatter(p[:, a], sgn * p[:, b], c=p[:, 2], s=0.3, cmap="rainbow_r", vmin=depth_range[0],
                                      vmax=depth_range[1], rasterized=True, linewidths=0)
                else:
                    axis.scatter(p[:, a], sgn * p[:, b], c=colours[cls], s=0.3, rasterized=True, linewidths=0)
            axis.set_title(f"{name}, coloured by {'depth' if row == 0 else 'class'}")
            axis.set_xlabel(xl)
            axis.set_ylabel(yl)
            axis.set_aspect("equal", adjustable="datalim")
            axis.grid(alpha=0.3)
    if sc is not None:
        fig.colorbar(sc, ax=ax[0, :], label="depth (m)", shrink=0.8)
    handles = [Line2D([], [], ls="", marker="o", color=CLASS_COLOURS[c], label=c) for c in PLANE_CLASSES]
    ax[1, 1].legend(handles=handles, loc="best", fontsize=8, markerscale=1.2)
    st = planes.stats
    fig.suptitle(f"{title}  —  {planes.method}: {len(planes)} planes, {len(planes.points)} points, "
                 f"inliers {st.inlier_pct:.1f} %, outliers {st.outlier_pct:.1f} %, {st.elapsed_ms:.1f} ms")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
