"""`kosmap planes LOG|FOLDER --out DIR`: FSPF+ (or FSPF) over every depth frame, with Table 5.2 statistics,
plane points and normals (npz and MCAP), processed depth PNGs and Fig. 5.2-style figures (mapping/planes/)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import options as O


def _check_args(path: Path, every: int, limit: int | None, figures: int) -> None:
    """Refuse a missing input and nonsense counts before anything is read or written."""
    if not path.exists():
        raise KosmapError(f"{path} does not exist; give a log (.mcap, .bag), a folder of depth images, or a dataset folder")
    if every < 1:
        raise KosmapError(f"--every {every} must be at least 1")
    if limit is not None and limit < 1:
        raise KosmapError(f"--max-frames {limit} must be at least 1; leave it out to filter every frame")
    if figures < 0:
        raise KosmapError(f"--figures {figures} must be 0 or more")


def _dataset_names(folder: Path, every: int, limit: int | None) -> list[str]:
    """The frame names of a dataset folder without decoding them (for the progress bar's total)."""
    from kosmap.tools.datasets import tum_frames

    n = folder.name
    if n == "tum_fr1_xyz":
        names = [str(p) for _, p in tum_frames(folder)]
    elif n == "open3d_rgbd_formats":
        names = ["TUM", "SUN", "NYU"]
    elif n == "slambook2_ch5_rgbd":
        names = [p.name for p in (folder / "depth").glob("*.pgm")]
    elif n == "cape_tunnel_frame":
        names = ["depth_0"]
    else:
        names = [p.name for p in folder.glob("*.pcd")]
    return names[::every][:limit]


def _source(path: Path, cfg, ov, every: int, limit: int | None, pattern: str | None):
    """The frames to filter: of the known datasets in a folder of ../shared/data/depth (tools/datasets.py), else
    of the log or the folder of depth images."""
    from kosmap.mapping.planes.frames import dataset_frames, log_frames
    from kosmap.tools.datasets import detect, iter_dataset

    folders = detect(path) if path.is_dir() and not pattern else []
    if not folders:
        return log_frames(path, cfg, ov, every, limit, pattern)
    if ov.fps is not None:
        raise KosmapError(f"--fps {ov.fps:g} applies to a folder of depth images; {path} holds datasets stamped by "
                          f"themselves")
    total = sum(len(_dataset_names(f, every, limit)) for f in folders)
    samples = ((j * every, s) for f in folders for j, s in enumerate(iter_dataset(f, limit, every)))
    return dataset_frames(samples, total, cfg, ov)


def register(app: typer.Typer) -> None:
    @app.command()
    def planes(
        source: Annotated[Path, typer.Argument(help="Log (.mcap, .bag), a folder of depth PNGs with a camera file, "
                                                     "or a folder of ../shared/data/depth datasets.")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder.")],
        method: Annotated[Optional[str], typer.Option("--method", help="fspf+ (thesis, default) or fspf (Biswas).")] = None,
        save_depth: Annotated[bool, typer.Option("--save-depth", help="Write the processed depth (plane points only) as 16-bit PNG (mm).")] = False,
        camera: Annotated[Optional[Path], typer.Option("--camera", help="Camera file (YAML/JSON: fx, fy, cx, cy[, depth_scale]); replaces the intrinsics of the folder, dataset or log.")] = None,
        depth_scale: Annotated[Optional[float], typer.Option("--depth-scale", help="Scale of 16-bit depth, either convention: 1 or more is image units per metre (1000 = mm, 5000 = TUM), below 1 metres per unit (0.001 = mm, RealSense); overrides the camera file and the dataset's own.")] = None,
        glob: Annotated[Optional[str], typer.Option("--glob", help="The depth images of a folder, by pattern (e.g. '*_depth.png'); without it images named rgb, color, label, mask or seg and 8-bit or colour images are skipped and counted.")] = None,
        fps: Annotated[Optional[float], typer.Option("--fps", help="Frame rate of a folder of depth images whose file names are not times (default 30); gravity from the frames tracks the floor by the frames' times.")] = None,
        figures: Annotated[int, typer.Option("--figures", help="How many frames get a Fig. 5.2-style figure (spread over the run).")] = 3,
        every: Annotated[int, typer.Option("--every", help="Process every Nth depth frame.")] = 1,
        max_frames: Annotated[Optional[int], typer.Option("--max-frames", help="Stop after this many frames.")] = None,
        seed: Annotated[Optional[int], typer.Option("--seed", help="Random seed: frame i (its index in the log or folder, counted before --every and --max-frames) uses seed + i, so a frame's planes are the same whatever --every; the same seed, the same planes.")] = None,
        no_mcap: Annotated[bool, typer.Option("--no-mcap", help="Do not write planes.mcap.")] = False,
        no_npz: Annotated[bool, typer.Option("--no-npz", help="Do not write planes/NNNNNN.npz.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None,
    ) -> None:
        """Plane filtering (FSPF+ or FSPF) of every depth frame: stats.csv (thesis Table 5.2), planes, figures."""
        sets = list(set_ or [])
        if method is not None:
            if method not in ("fspf+", "fspf"):
                raise KosmapError(f"--method {method} is not fspf+ or fspf")
            sets.append(f'fspf.method="{method}"')
        if seed is not None:
            sets.append(f"fspf.seed={seed}")
        cfg = O.make_config(config, sets, depth_topic, info_topic)
        from kosmap.mapping.planes.frames import read_override
        from kosmap.mapping.planes.run import PlanesOptions, run_planes
        from kosmap.mapping.runtime.outdir import check_out
        from kosmap.tools.progress import items_bar

        _check_args(source, every, max_frames, figures)  # everything checked before anything is read or written
        ov = read_override(camera, depth_scale, fps)
        check_out(out)
        frames = _source(source, cfg, ov, every, max_frames, glob)
        opts = PlanesOptions(save_depth=save_depth, figures=figures, mcap=not no_mcap, npz=not no_npz)
        with items_bar("planes", "frames") as tick:
            s = run_planes(source, out, cfg, frames, opts, on_progress=tick)
        for g in s["gravity"].values():
            floor = "" if g["floor_frames"] == g["frames"] else \
                f"; the floor known in {g['floor_frames']}, no plane ground in the others"
            print(f"gravity: {g['from']} ({g['frames']} frames{floor})")
        m = s["mount_estimate"]
        if m is not None:
            print(f"mount from the floor ({m['frames']} frames): pitch {m['pitch_deg']:.2f}°, roll {m['roll_deg']:.2f}°, "
                  f"height {m['height_m']:.3f} m; given: pitch {m['given_pitch_deg']:.2f}°, roll {m['given_roll_deg']:.2f}°, "
                  f"height {m['given_height_m']:.3f} m ({out}/mount.toml)")
        print(f"{s['frames']} frames, {s['method']}: median {s['median_ms']:.2f} ms, p90 {s['p90_ms']:.2f} ms "
              f"per frame; of the pixels: ineligible {s['ineligible_pct']:.1f} %, inliers {s['inlier_pct']:.1f} %, "
              f"dropped {s['dropped_pct']:.1f} %, outliers {s['outlier_pct']:.1f} %, "
              f"not examined {s['unexamined_pct']:.1f} %; {s['planes']:.1f} planes per frame")
        for w in s["warnings"]:
            print(f"warning: {w}")
        print(f"wrote {out}/stats.csv, config.toml, summary.json" + ("" if no_npz else ", planes/")
              + ("" if no_mcap else ", planes.mcap") + (", depth/" if save_depth else "") + (", figures/" if figures else "") + (", mount.toml" if m is not None else ""))
