"""[kos] levels that cannot make a map are refused in one line (empty, repeated, below the floor, outside the
obstacle scan's heights), and a list-valued key takes `--set key=a,b,c` or says how to write a list."""

from __future__ import annotations

import pytest

from kosmap.frontend.errors import ConfigError
from kosmap.frontend.kos import KosConfig
from kosmap.mapping.config import load_config
from kosmap.tools.cli import main


def one_line_error(capsys, *argv: str) -> str:
    """Run `kosmap build` on a log that is never read (the config fails first); its single error line."""
    code = main(["build", "never_read.mcap", "--out", "never_written", *argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("kosmap: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


@pytest.mark.parametrize("sets, words", [
    (["kos.levels=[5.0]"], "config [kos] levels: 5 m ± band 0.1 m reaches above obstacle_max = 1.9 m, the top of the "
                           "obstacle scan: give heights from 0.15 to 1.8 m, e.g. [0.3, 0.75, 1.5], or raise [kos] obstacle_max"),
    (["kos.levels=[-1,0.5]"], "config [kos] levels: -1 m is not above the floor (levels are heights above it, in "
                              "base_link): give heights from 0.15 to 1.8 m, e.g. [0.3, 0.75, 1.5]"),
    (["kos.levels=-1,0.5"], "-1 m is not above the floor"),  # the comma form reaches the same check
    (["kos.levels=[0, 0.5]"], "0 m is not above the floor"),
    (["kos.levels=[0.1]"], "config [kos] levels: 0.1 m ± band 0.1 m reaches below obstacle_min = 0.05 m, into the "
                           "floor: give heights from 0.15 to 1.8 m, e.g. [0.3, 0.75, 1.5], or narrow [kos] band"),
    (["kos.levels=[0.3,0.3]"], "config [kos] levels = [0.3, 0.3] repeats 0.3 m: give each height once (a scan and a map each)"),
    (["kos.levels=[0.301,0.304]"], "has 0.301 and 0.304 m, both named h0_30 (levels are named to the centimetre): "
                                   "give heights at least 1 cm apart"),
    (["kos.levels=[]"], "config [kos] levels = [] is empty: give heights from 0.15 to 1.8 m, e.g. [0.3, 0.75, 1.5]"),
    (["kos.band=1"], "config [kos] band = 1 m is too wide"),
    (["kos.levels=[1.5]", "kos.obstacle_max=1.2"], "give heights from 0.15 to 1.1 m, or raise"),  # no e.g. that does not fit
    (["kos.levels=abc"], "config [kos] levels = 'abc' must be a list, e.g. --set 'kos.levels=[0.3,0.75,1.5]' or "
                         "--set kos.levels=0.3,0.75,1.5"),
    (["depth.mount_xyz=high"], "must be a list, e.g. --set 'depth.mount_xyz=[0,0,1]' or --set depth.mount_xyz=0,0,1"),
])
def test_levels_and_lists_that_cannot_work_are_refused_in_one_line(capsys, sets, words):
    err = one_line_error(capsys, *[a for s in sets for a in ("--set", s)])
    assert words in err, err


@pytest.mark.parametrize("levels", [[0.3, 0.75, 1.5], [0.15, 0.5, 0.75], [1.8], [0.2, 0.45, 0.75, 1.0, 1.25, 1.5]])
def test_the_thesis_levels_and_those_at_the_band_limits_stay_valid(levels):
    """The defaults, tests/frontend/test_kos_sim.py's 0.15 m (0.15 − 0.1 is a hair under 0.05 in floats), the top
    level 1.8 m (1.9 − 0.1) and tools/bench_kos.py's six levels."""
    assert KosConfig(levels=levels).levels == levels
    assert load_config(None, [f"kos.levels={levels}"]).kos.levels == levels


def test_a_higher_level_is_valid_with_a_higher_obstacle_scan():
    assert load_config(None, ["kos.levels=[2.0]", "kos.obstacle_max=2.2"]).kos.levels == [2.0]


def test_the_kos_config_refuses_bad_levels_when_built_in_code_too():
    for levels, words in (([], "is empty"), ([5.0], "above obstacle_max"), ([-1.0, 0.5], "not above the floor"),
                          ([0.3, 0.3], "repeats 0.3 m")):
        with pytest.raises(ConfigError, match=words):
            KosConfig(levels=levels)


@pytest.mark.parametrize("text, key, value", [
    ("kos.levels=0.3,0.75,1.5", "levels", [0.3, 0.75, 1.5]),  # as `kosmap scan --levels 0.3,0.75,1.5`
    ("kos.levels=0.3, 0.75", "levels", [0.3, 0.75]),
    ("kos.levels=0.5", "levels", [0.5]),  # one number: a list of one
    ("kos.levels=[0.3,0.75]", "levels", [0.3, 0.75]),  # TOML as before
    ("fspf.drop_classes=ground,ceiling", "drop_classes", ["ground", "ceiling"]),
    ("fspf.drop_classes=[ground]", "drop_classes", ["ground"]),  # brackets without TOML's quotes
    ("topics.depth=/cam1/depth,/cam2/depth", "depth", ["/cam1/depth", "/cam2/depth"]),
    ("depth.mount_xyz=0,0,1.2", "mount_xyz", [0.0, 0.0, 1.2]),
    ("topics.depth=5", "depth", ["5"]),  # a topic stays a string
])
def test_list_keys_take_comma_separated_items_in_set(text, key, value):
    cfg = load_config(None, [text])
    section = text.split(".")[0]
    got = getattr(getattr(cfg, section), key)
    assert got == value and all(type(a) is type(b) for a, b in zip(got, value))


def test_a_bad_item_in_brackets_is_named_and_a_bad_bare_value_gets_the_list_syntax():
    with pytest.raises(ConfigError, match=r"levels = 'abc' is not a number"):
        load_config(None, ["kos.levels=[0.3,abc]"])
    with pytest.raises(ConfigError, match=r"must be a list, e\.g\. --set 'kos\.levels=\[0\.3,0\.75,1\.5\]'"):
        load_config(None, ["kos.levels=0.3,,0.5"])


def test_a_toml_file_gets_the_toml_syntax(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('[kos]\nlevels = "0.3,0.75"\n')
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert str(e.value) == "config [kos] levels = '0.3,0.75' must be a list, e.g. levels = [0.3, 0.75, 1.5] under [kos]"


def test_a_config_toml_of_an_earlier_kosmap_still_loads_and_a_retired_choice_is_explained(tmp_path):
    """[fspf] backend = "numba" (what earlier builds wrote into config.toml) changes nothing and is dropped; the numpy
    backend, now a benchmark's reference only, is refused with the reason."""
    old = tmp_path / "config.toml"
    old.write_text('[fspf]\nbackend = "numba"\nn_min = 60\n')
    assert load_config(old).fspf.n_min == 60
    with pytest.raises(ConfigError, match=r"\[fspf\] backend = 'numpy' is no longer a setting: .*; drop the key"):
        load_config(None, ["fspf.backend=numpy"])
