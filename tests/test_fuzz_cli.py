"""Fuzzing the command line (issue 17): every subcommand with valid and hostile arguments, files
and settings.

`vogjax.cli.main` runs in-process. A call either succeeds (exit 0, its outputs there and
readable) or exits 2 with stderr ending in one line `vogjax CMD: error: ...` that names the
argument, file or setting at fault, with no traceback, and leaves every file in the working
folder as it was. Any other exception escaping `main` is a raw traceback: a finding. Valid runs
that take long (mapping, exploring, the demo) are kept rare or out; see test_faults.py for runs
killed midway. Helpers and settings: tests/test_fuzz_maps.py.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import assume, event, given
from hypothesis import strategies as st

import vogjax as vj
from vogjax import cli
from vogjax.io.dataset import Dataset

from . import submap_helpers as helpers
from .test_fuzz_maps import CFG, bounded, fuzz

SCENES = "propeller, pilings, tank, boxes"  # a bad scene's error lists them (it says "name", not --scene)
SIM_SCANS = 25  # every simulation here records this many scans (one MJX compilation for all)
TINY_SETTINGS = (
    "[timing]\nrays = 100\nevery_submaps = 0\n[report]\nsurface_points = 500\n[pipeline]\nscans_per_submap = 10\n"
)


class Workspace:
    """A folder of inputs, good and bad, copied fresh for every example."""

    def __init__(self, template: Path, root: Path):
        self.root = root
        shutil.copytree(template, root)

    def __repr__(self) -> str:
        return "Workspace()"

    def __truediv__(self, name: str) -> Path:
        return self.root / name

    def snapshot(self) -> dict:
        return {
            str(p.relative_to(self.root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(self.root.rglob("*"))
        }


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """run.h5 (a 25-scan boxes survey), maps, damaged copies, settings files, a folder, a text file."""
    root = tmp_path_factory.mktemp("cli") / "template"
    root.mkdir()
    assert cli.main(["simulate", "--scene", "boxes", "--scans", str(SIM_SCANS), "--out", str(root / "run.h5")]) == 0
    data = (root / "run.h5").read_bytes()
    (root / "truncated.h5").write_bytes(data[: len(data) // 2])
    with h5py.File(root / "run.h5", "r") as f:
        chunk = f["ranges"].id.get_chunk_info(0)  # a checksummed data chunk
    flipped = bytearray(data)
    flipped[chunk.byte_offset + chunk.size // 2] ^= 0xFF
    (root / "flipped.h5").write_bytes(bytes(flipped))
    vog = helpers.random_vog(np.random.default_rng(0), 2, CFG, scans=2, beams=30, spread=2.0)
    vog.submap(0).save(root / "voxel.vog")
    gmap = vj.GlobalMap(CFG)
    gmap.merge(vog)
    gmap.save(root / "global.vog")
    saved = (root / "voxel.vog").read_bytes()
    (root / "damaged.vog").write_bytes(saved[:-1] + bytes([saved[-1] ^ 1]))
    (root / "tiny.toml").write_text(TINY_SETTINGS)
    (root / "typo.toml").write_text("[map]\nvoxel_sise = 0.1\n")
    (root / "type.toml").write_text("[map]\nvoxel_size = 'small'\n")
    (root / "range.toml").write_text("[map]\nmax_range = 1e300\n")
    (root / "table.toml").write_text("[maps]\nvoxel_size = 0.1\n")
    (root / "huge.toml").write_text(TINY_SETTINGS.replace("rays = 100", "rays = 9223372036854775807"))
    (root / "broken.toml").write_text("[map\n")
    (root / "binary.toml").write_bytes(b"\xff\xfe\x00\x01")
    (root / "notes.txt").write_text("not a run\n")
    (root / "folder").mkdir()
    (root / "folder" / "inside.txt").write_text("x")
    return root


@pytest.fixture
def workspace_factory(template, tmp_path_factory):
    def make() -> Workspace:
        return Workspace(template, tmp_path_factory.mktemp("ws") / "w")

    return make


def run_cli(argv, capsys):
    """(exit code, stdout, stderr) of `vogjax argv`; any exception but SystemExit escapes."""
    # a command may compile the vehicle or a kernel first: seconds alone, a minute on a loaded machine
    with bounded("vogjax " + " ".join(map(str, argv)), limit_s=120.0):
        try:
            code = cli.main([str(a) for a in argv])
        except SystemExit as exit:
            code = exit.code
    out, err = capsys.readouterr()
    return code, out, err


def check_refusal(code, err, names, argv):
    """Exit 2, no traceback, stderr ending in one `vogjax ...: error: ...` line naming one of `names`."""
    assert code == 2, f"vogjax {argv}: exit {code}"
    assert "Traceback" not in err
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
    last = lines[-1]
    assert last.startswith("vogjax") and ": error: " in last, f"last stderr line: {last!r}"
    assert any(str(name) in last for name in names), f"{last!r} names none of {names}"


@st.composite
def chosen(draw, good: list, bad: list):
    """(value, names) where names is None for a good value, else what an error must name."""
    if draw(st.integers(0, 2)) == 0 and bad:
        value, names = draw(st.sampled_from(bad))
        return value, names
    return draw(st.sampled_from(good)), None


EITHER = "either"  # first of a value's names: it may be accepted; if refused, the rest are named


def args_of(pairs: list) -> tuple[list, list]:
    """argv pieces and the names of every bad (or doubtful) one."""
    argv, bad = [], []
    for flag, (value, names) in pairs:
        if value is None:
            continue
        argv += [flag] if value is True else [flag, value]
        if names is not None:
            bad.append(names)
    return argv, bad


def outcome(code, err, bad, argv, before, after):
    """Exit 2 naming a bad argument with nothing changed, or exit 0 only when nothing was bad."""
    definite = [names for names in bad if names[0] != EITHER]
    if code == 0:
        assert not definite, f"vogjax {argv}: accepted bad arguments {definite}"
        return True
    check_refusal(code, err, [n for names in bad for n in names if n != EITHER] or ["error"], argv)
    assert bad, f"vogjax {argv}: refused good arguments: {err.splitlines()[-1]}"
    assert before == after, "a refused command changed files"
    return False


# ------------------------------------------------------------------------------ simulate


@fuzz(20)
@given(data=st.data())
def test_cli_simulate(workspace_factory, capsys, data):
    ws = workspace_factory()
    scene = data.draw(chosen(["boxes"], [(name, ["scene", SCENES]) for name in ("nope", "", "BOXES", "../boxes")]))
    out = data.draw(
        chosen(
            [ws / "new.h5"],
            [
                (ws / "run.h5", ["run.h5"]),
                (ws / "folder", ["folder"]),
                (ws / "missing" / "x.h5", ["missing"]),
                (ws / "notes.txt" / "x.h5", ["notes.txt"]),
            ],
        )
    )
    overwrite = data.draw(st.sampled_from([None, True]))
    if overwrite and out[0] == ws / "run.h5":
        out = (out[0], None)  # replacing it is what --overwrite is for
    scans = data.draw(
        chosen(
            [SIM_SCANS],
            [
                (0, ["scans"]),
                (-1, ["scans"]),
                (10**8, ["scans"]),
                ("x", ["--scans"]),
                ("1e3", ["--scans"]),
                ("", ["--scans"]),
            ],
        )
    )
    laps = data.draw(chosen([None, 1, 2], [(0, ["laps"]), (-3, ["laps"]), (1001, ["laps"]), ("two", ["--laps"])]))
    # (a negative seed: test_negative_seed_is_refused_naming_it)
    seed = data.draw(chosen([0, 7], [("x", ["--seed"]), (2**70, [EITHER, "seed"])]))
    noise = data.draw(
        chosen(
            [0.02, 0.0],
            [
                (-1.0, ["range", "noise"]),
                ("nan", ["range", "noise"]),
                ("inf", ["range", "noise"]),
                ("x", ["--range-noise"]),
                (1e300, [EITHER, "range", "noise", "ranges"]),
            ],
        )
    )
    argv, bad = args_of(
        [
            ("--scene", scene),
            ("--out", out),
            ("--scans", scans),
            ("--laps", laps),
            ("--seed", seed),
            ("--range-noise", noise),
            ("--overwrite", (overwrite, None)),
        ]
    )
    event("simulated" if not [names for names in bad if names[0] != EITHER] else "refused or doubtful")
    before = ws.snapshot()
    code, _, err = run_cli(["simulate", *argv], capsys)
    if outcome(code, err, bad, argv, before, ws.snapshot()):
        with Dataset(out[0]) as run:
            run.validate()
            assert len(run) == SIM_SCANS


# ------------------------------------------------------------------------------ map


@fuzz(15)
@given(data=st.data())
def test_cli_map(workspace_factory, capsys, data):
    ws = workspace_factory()
    runs = data.draw(
        st.lists(
            chosen(
                [ws / "run.h5"],
                [
                    (ws / "missing.h5", ["missing.h5"]),
                    (ws / "truncated.h5", ["truncated.h5"]),
                    (ws / "flipped.h5", ["flipped.h5"]),
                    (ws / "notes.txt", ["notes.txt"]),
                    (ws / "folder", ["folder"]),
                    (ws / "voxel.vog", ["voxel.vog"]),
                ],
            ),
            min_size=1,
            max_size=2,
        )
    )
    if len(runs) == 2 and runs[0][0] == runs[1][0]:
        runs[1] = (runs[1][0], ["share an output folder", "paths"])
    out = data.draw(
        chosen([ws / "maps"], [(ws / "notes.txt", ["notes.txt"]), (ws / "notes.txt" / "sub", ["notes.txt"])])
    )
    config = data.draw(
        chosen(
            [ws / "tiny.toml"],
            [
                (ws / "typo.toml", ["voxel_sise"]),
                (ws / "type.toml", ["voxel_size"]),
                (ws / "range.toml", ["max_range"]),
                (ws / "table.toml", ["maps"]),
                (ws / "huge.toml", ["rays"]),
                (ws / "broken.toml", ["broken.toml"]),
                (ws / "binary.toml", ["binary.toml"]),
                (ws / "nope.toml", ["nope.toml"]),
                (ws / "folder", ["folder"]),
            ],
        )
    )
    preset = data.draw(chosen([None, "default"], [("fast", ["preset"]), ("", ["preset"])]))
    workers = data.draw(chosen([None], [(0, ["workers"]), (-2, ["workers"]), ("many", ["--workers"])]))
    crm = data.draw(st.sampled_from([None, True]))
    argv = [str(r[0]) for r in runs]
    more, bad = args_of(
        [
            ("--out", out),
            ("--config", config),
            ("--preset", preset),
            ("--workers", workers),
            ("--crm", (crm, None)),
            ("--quiet", (True, None)),
        ]
    )
    argv += more
    bad += [r[1] for r in runs if r[1] is not None]
    event("mapped" if not bad else "refused")
    before = ws.snapshot()
    code, _, err = run_cli(["map", *argv], capsys)
    if outcome(code, err, bad, argv, before, ws.snapshot()):
        gmap = vj.GlobalMap.load(out[0] / "run" / "global_map.vog")
        assert gmap.applied_ids and (out[0] / "run" / "report.json").is_file()


# ------------------------------------------------------------------------------ export, view, import


@fuzz(30)
@given(data=st.data())
def test_cli_export(workspace_factory, capsys, data):
    ws = workspace_factory()
    source = data.draw(
        chosen(
            [ws / "voxel.vog", ws / "global.vog"],
            [
                (ws / "damaged.vog", ["damaged.vog"]),
                (ws / "missing.vog", ["missing.vog"]),
                (ws / "run.h5", ["run.h5"]),
                (ws / "folder", ["folder"]),
                (ws / "notes.txt", ["notes.txt"]),
            ],
        )
    )
    fmt = data.draw(chosen([None, "bt", "ot", "ply"], [("xyz", ["--format"]), ("", ["--format"])]))
    suffix = data.draw(st.sampled_from([".bt", ".ot", ".ply", ".txt", ""]))
    out = data.draw(
        chosen(
            [ws / f"out{suffix}"],
            [
                (ws / "folder", ["folder", "--out"]),
                (ws / "missing" / f"x{suffix}", ["missing", "--out"]),
                (ws / "notes.txt" / f"x{suffix}", ["notes.txt", "--out"]),
            ],
        )
    )
    if fmt[0] is None and suffix not in (".bt", ".ot", ".ply") and out[1] is None:
        out = (out[0], ["--format", "--out"])  # the format must come from somewhere
    implied = out[0].suffix.lstrip(".")
    if fmt[0] in ("bt", "ot", "ply") and implied in ("bt", "ot", "ply") and implied != fmt[0]:
        out = (out[0], [*(out[1] or []), "--format", "--out"])  # the suffix names another format
    argv, bad = args_of([("--format", fmt), ("--out", out)])
    argv = [source[0], *argv]
    if source[1] is not None:
        bad.append(source[1])
    before = ws.snapshot()
    code, _, err = run_cli(["export", *argv], capsys)
    if outcome(code, err, bad, argv, before, ws.snapshot()):
        assert out[0].is_file() and out[0].stat().st_size > 0


@pytest.fixture(scope="module")
def rerun():
    return pytest.importorskip("rerun")


@fuzz(20)
@given(data=st.data())
def test_cli_view(rerun, workspace_factory, capsys, data):
    ws = workspace_factory()
    source = data.draw(
        chosen(
            [ws / "voxel.vog", ws / "global.vog"],
            [
                (ws / "damaged.vog", ["damaged.vog"]),
                (ws / "missing.vog", ["missing.vog"]),
                (ws / "folder", ["folder"]),
                (ws / "notes.txt", ["notes.txt"]),
            ],
        )
    )
    save = data.draw(
        chosen(
            [ws / "rec.rrd"],
            [
                (ws / "rec.txt", ["--save", "rec.txt"]),
                (ws / "missing" / "r.rrd", ["missing"]),
                (ws / "folder", ["folder"]),
            ],
        )
    )
    argv, bad = args_of([("--save", save)])
    argv = [source[0], *argv]
    if source[1] is not None:
        bad.append(source[1])
    before = ws.snapshot()
    code, _, err = run_cli(["view", *argv], capsys)
    if outcome(code, err, bad, argv, before, ws.snapshot()):
        assert save[0].is_file() and save[0].stat().st_size > 0


@fuzz(20)
@given(data=st.data())
def test_cli_import(workspace_factory, capsys, data):
    """No bag here is a real one: every call is refused, naming the bag, the --max-range or --out."""
    ws = workspace_factory()
    # (a folder that is no ROS 2 bag: test_import_of_a_folder_that_is_no_bag)
    bag = data.draw(
        st.sampled_from(
            [
                (ws / "missing.bag", ["missing.bag"]),
                (ws / "notes.txt", ["notes.txt"]),
                (ws / "run.h5", ["run.h5"]),
                (ws / "voxel.vog", ["voxel.vog"]),
            ]
        )
    )
    topic = data.draw(st.sampled_from(["/points", "", "not a topic", "/" * 50]))
    max_range = data.draw(
        chosen(
            [None, 5.0],
            [
                (-1.0, ["max_range", "max-range"]),
                ("nan", ["max_range", "max-range"]),
                ("x", ["--max-range"]),
                (1e300, ["max_range", "max-range"]),
            ],
        )
    )
    out = data.draw(chosen([ws / "imported.h5"], [(ws / "run.h5", ["run.h5"]), (ws / "missing" / "i.h5", ["missing"])]))
    argv, bad = args_of(
        [
            ("--points", (topic, None)),
            ("--odometry", ("/odom", None)),
            ("--max-range", max_range),
            ("--out", out),
            ("--quiet", (True, None)),
        ]
    )
    argv = [bag[0], *argv]
    bad.append(bag[1])
    before = ws.snapshot()
    code, _, err = run_cli(["import", *argv], capsys)
    assert not outcome(code, err, bad, argv, before, ws.snapshot())


# ------------------------------------------------------------------------------ explore, demo, the command itself


@fuzz(20)
@given(data=st.data())
def test_cli_explore(workspace_factory, capsys, data):
    """A long run: only calls with at least one bad argument (each must be refused up front).
    (`vogjax demo`: test_refused_demo_leaves_nothing, test_demo_into_a_file_is_refused.)"""
    ws = workspace_factory()
    scene = data.draw(chosen(["boxes"], [(name, ["scene", SCENES]) for name in ("nope", "")]))
    submaps = data.draw(chosen([2], [(0, ["submaps"]), (-1, ["submaps"]), ("x", ["--submaps"])]))
    seed = data.draw(chosen([0], [(-1, ["seed"]), ("x", ["--seed"])]))
    config = data.draw(
        chosen(
            [None],
            [
                (ws / "typo.toml", ["voxel_sise"]),
                (ws / "broken.toml", ["broken.toml"]),
                (ws / "nope.toml", ["nope.toml"]),
            ],
        )
    )
    kind = data.draw(chosen(["global"], [("octomap", ["--map"])]))
    # (an existing run file: test_explore_keeps_an_existing_run)
    out = data.draw(chosen([ws / "explored.h5"], [(ws / "folder", ["folder"]), (ws / "missing" / "e.h5", ["missing"])]))
    argv, bad = args_of(
        [
            ("--scene", scene),
            ("--submaps", submaps),
            ("--seed", seed),
            ("--config", config),
            ("--map", kind),
            ("--out", out),
            ("--quiet", (True, None)),
        ]
    )
    assume(bad)
    before = ws.snapshot()
    code, _, err = run_cli(["explore", *argv], capsys)
    assert not outcome(code, err, bad, argv, before, ws.snapshot())


@fuzz(20)
@given(
    argv=st.lists(
        st.sampled_from(
            ["", "mapp", "--out", "-x", "simulate", "map", "--help", "--version", "view", "\x00", "é", "--scene=boxes"]
        ),
        max_size=3,
    )
)
def test_cli_top_level(capsys, argv):
    """Unknown commands and options: argparse's exit 2 (or 0 for --help), never a traceback."""
    assume(not (argv and argv[0] in ("simulate", "map", "view") and "--help" not in argv))
    code, out, err = run_cli(argv, capsys)
    assert code in (0, 2) and "Traceback" not in err
    if code == 2:
        assert err.strip().splitlines()[-1].startswith("vogjax")


# ------------------------------------------------------------------------------ findings, fixed (regression tests)


def test_import_of_a_folder_that_is_no_bag(workspace_factory, capsys):
    ws = workspace_factory()
    try:
        code, _, err = run_cli(
            ["import", ws / "folder", "--points", "/p", "--odometry", "/o", "--out", ws / "i.h5"], capsys
        )
    except OSError as error:
        raise AssertionError(f"{type(error).__name__}: {error}") from None
    check_refusal(code, err, ["folder"], "import")


@pytest.mark.parametrize("argv", [["--scene", "nope"], ["--laps", "0"]], ids=["scene", "laps"])
def test_refused_demo_leaves_nothing(workspace_factory, capsys, argv):
    ws = workspace_factory()
    before = ws.snapshot()
    code, _, err = run_cli(["demo", *argv, "--out", ws / "demo", "--quiet"], capsys)
    check_refusal(code, err, ["scene", SCENES, "laps"], argv)
    assert ws.snapshot() == before, "the refused demo left files behind"


@pytest.mark.parametrize("out", ["notes.txt", "notes.txt/demo"])
def test_demo_into_a_file_is_refused(workspace_factory, capsys, out):
    ws = workspace_factory()
    try:
        code, _, err = run_cli(["demo", "--scene", "boxes", "--laps", "1", "--out", ws / out, "--quiet"], capsys)
    except OSError as error:
        raise AssertionError(f"{type(error).__name__}: {error}") from None
    check_refusal(code, err, ["notes.txt"], out)


def test_negative_seed_is_refused_naming_it(workspace_factory, capsys):
    ws = workspace_factory()
    code, _, err = run_cli(
        ["simulate", "--scene", "boxes", "--scans", SIM_SCANS, "--seed", -1, "--out", ws / "s.h5"], capsys
    )
    check_refusal(code, err, ["seed"], "simulate --seed -1")


class _Explored(Exception):
    pass


def test_explore_keeps_an_existing_run(workspace_factory, capsys, monkeypatch):
    """Checked without exploring: the exploration loop raises as soon as it is built."""
    from vogjax.sim import explore

    def stop(*args, **kwargs):
        raise _Explored

    monkeypatch.setattr(explore, "_Loop", stop)
    ws = workspace_factory()
    try:
        code, _, err = run_cli(
            ["explore", "--scene", "boxes", "--submaps", 2, "--out", ws / "run.h5", "--quiet"], capsys
        )
    except _Explored:
        raise AssertionError("explore set out to replace the existing run.h5") from None
    check_refusal(code, err, ["run.h5"], "explore")
