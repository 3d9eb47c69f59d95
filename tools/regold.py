"""The golden digests of `kosmap build` on short simulated logs (tests/mapping/test_golden_build.py).

`python -m kosmap.tools.regold` builds the sample logs again and rewrites tests/mapping/golden_build.json: run it
when a change is meant to change the maps, trajectories or kosmap.mcap, and say in the commit why they changed.
The digests cover what a build writes deterministically (the same bytes on a run, a rerun, serial or parallel):
every map (PGM, PNG, YAML), every trajectory (TUM), and kosmap.mcap's messages (topic, schema, log and publish
time, payload; not the file's bytes, which also hold the writer library's name and the chunk compression). Files
that carry timings (stats.csv, metrics.json, the report and its figures) are left out.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

GOLDEN = Path(__file__).resolve().parents[1] / "tests" / "mapping" / "golden_build.json"
SETS = ["build.mcap_planes_period=0.5", "build.depth_rate=0"]  # every depth frame; a cloud every 0.5 s in the MCAP
DIGESTED = ("map_*.pgm", "map_*.png", "map_*.yaml", "*.tum")


@dataclass(frozen=True)
class Sample:
    """A simulated log to build: the world, the simulator's seed and duration, and a rear camera or not."""

    name: str
    world: str
    seed: int
    duration: float
    rear_camera: bool = False


SAMPLES = (Sample("room", "room", 4, 2.5), Sample("office_two_cameras", "office", 7, 2.0, rear_camera=True))


def build_sample(sample: Sample, folder: Path, workers: int = 0) -> Path:
    """Simulate `sample` into `folder` and build it there (out: folder/build); returns the build's folder."""
    from kosmap.mapping.build import build
    from kosmap.mapping.config import load_config
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    world = load_world(sample.world)
    log = folder / f"{sample.name}.mcap"
    simulate(world, SimConfig(seed=sample.seed, duration=sample.duration, rear_camera=sample.rear_camera), log)
    blueprint = write_map_server(world.blueprint(0.05), folder / f"{sample.name}_bp.yaml", ".png")
    out = folder / "build"
    build(log, out, load_config(None, SETS), blueprint=blueprint, workers=workers)
    return out


def mcap_digest(path: Path) -> tuple[str, int]:
    """SHA-256 over the MCAP's messages in log order (topic, schema, log time, publish time, payload), and their
    count."""
    from mcap.reader import make_reader

    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            for part in (channel.topic.encode(), (schema.name if schema else "").encode(),
                         msg.log_time.to_bytes(8, "little"), msg.publish_time.to_bytes(8, "little"), msg.data):
                h.update(len(part).to_bytes(8, "little"))
                h.update(part)
            n += 1
    return h.hexdigest(), n


def digests(out: Path) -> dict:
    """The digests of a build's folder: SHA-256 per map and trajectory file, and kosmap.mcap's messages."""
    files = sorted({p.name for pat in DIGESTED for p in out.glob(pat)})
    mcap, n = mcap_digest(out / "kosmap.mcap")
    return {"files": {f: hashlib.sha256((out / f).read_bytes()).hexdigest() for f in files},
            "kosmap.mcap messages": mcap, "kosmap.mcap message count": n}


def main() -> None:
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=GOLDEN, help="the golden file to write")
    args = ap.parse_args()
    golden = {}
    for s in SAMPLES:
        with tempfile.TemporaryDirectory() as d:
            golden[s.name] = digests(build_sample(s, Path(d)))
        print(f"{s.name}: {len(golden[s.name]['files'])} files, "
              f"{golden[s.name]['kosmap.mcap message count']} messages in kosmap.mcap")
    args.out.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
