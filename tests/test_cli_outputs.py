"""What the commands write, and what they refuse to write (issue review of the CLI's outputs):
`export` never over its own map nor under a suffix of another format, `simulate` and `demo`
check every output before flying the survey, any --range-noise makes a valid run, an OctoMap
import writes a .vog, and `view` says at once that there is no display (and reaps a failed
viewer). Refusals are one stderr line with exit 2 (`refused`), leaving the files as they were.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.commands import view as view_command
from vogjax.io.dataset import Dataset
from vogjax.sim import vehicle

from . import submap_helpers as helpers
from .test_cli_help import refused
from .test_fuzz_maps import CFG

SIM_SCANS = 25  # as test_fuzz_cli's runs: one MJX compilation for all in a worker


@pytest.fixture(scope="module")
def global_vog(tmp_path_factory) -> Path:
    """A small GlobalMap file (random scans, no simulation)."""
    path = tmp_path_factory.mktemp("outputs") / "global.vog"
    gmap = vj.GlobalMap(CFG)
    gmap.merge(helpers.random_vog(np.random.default_rng(0), 2, CFG, scans=2, beams=30, spread=2.0))
    gmap.save(path)
    return path


@pytest.fixture
def no_flight(monkeypatch):
    """Simulating fails the test: a refusal must come before the survey is flown."""

    def fly(*args, **kwargs):
        raise AssertionError("the survey was flown before the refusal")

    monkeypatch.setattr(vehicle, "simulate", fly)


def files_in(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


# ------------------------------------------------------------------------------ 1. export


def test_export_refuses_to_write_over_its_own_map(global_vog, tmp_path, capsys):
    source = tmp_path / "g.vog"
    source.write_bytes(global_vog.read_bytes())
    (tmp_path / "link.vog").symlink_to(source)
    os.link(source, tmp_path / "hard.vog")
    before = files_in(tmp_path)
    for out in (source, tmp_path / "." / "g.vog", tmp_path / "link.vog", tmp_path / "hard.vog"):
        line = refused(capsys, ["export", source, "--format", "bt", "--out", out])
        assert "--out" in line and str(out) in line and "is the map being exported" in line
    line = refused(capsys, ["export", tmp_path / "link.vog", "--format", "bt", "--out", source])  # a link to it
    assert "--out" in line
    assert files_in(tmp_path) == before


def test_export_refuses_a_format_its_out_suffix_contradicts(global_vog, tmp_path, capsys):
    for format, name in (("ply", "x.bt"), ("bt", "x.ot"), ("ot", "x.PLY")):
        line = refused(capsys, ["export", global_vog, "--format", format, "--out", tmp_path / name])
        assert f"--format {format}" in line and "--out" in line and name in line
    assert not list(tmp_path.iterdir())
    # a suffix that names no format leaves the choice to --format; an agreeing one is fine
    for format, name in (("ply", "x.txt"), ("bt", "x.bt")):
        assert cli.main(["export", str(global_vog), "--format", format, "--out", str(tmp_path / name), "-q"]) == 0
        assert (tmp_path / name).stat().st_size > 0
    assert (tmp_path / "x.txt").read_bytes().startswith(b"ply")


# ------------------------------------------------------------------------------ 2. outputs before the survey


def test_simulate_refuses_a_missing_out_folder_before_flying(no_flight, tmp_path, capsys):
    out = tmp_path / "nodir" / "x.h5"
    line = refused(capsys, ["simulate", "--scene", "propeller", "--out", out, "-q"])
    assert "--out" in line and f"folder {str(out.parent)!r} does not exist" in line
    assert not list(tmp_path.iterdir())


def test_demo_checks_its_report_folder_before_flying(no_flight, tmp_path, capsys):
    out = tmp_path / "demo2"
    out.mkdir()
    (out / "boxes").write_text("in the way of the report folder")
    before = files_in(out)
    line = refused(capsys, ["demo", "--scene", "boxes", "--laps", "1", "--out", out, "-q"])
    assert f"{str(out / 'boxes')!r} is a file" in line
    assert files_in(out) == before  # no boxes.h5


def test_demo_checks_its_run_file_before_flying(no_flight, tmp_path, capsys):
    (tmp_path / "boxes.h5").mkdir()
    line = refused(capsys, ["demo", "--scene", "boxes", "--laps", "1", "--out", tmp_path, "-q"])
    assert f"{str(tmp_path / 'boxes.h5')!r} is a folder" in line


# ------------------------------------------------------------------------------ 3. range noise


def test_large_range_noise_makes_a_valid_run(tmp_path, capsys):
    """0.5 m of noise takes some returns below zero: invalid beams, not a run the writer refuses."""
    out = tmp_path / "rn.h5"
    argv = ["simulate", "--scene", "boxes", "--scans", SIM_SCANS, "--range-noise", "0.5", "--out", out, "-q"]
    assert cli.main([str(a) for a in argv]) == 0
    assert capsys.readouterr().err == ""
    with Dataset(out) as run:
        run.validate()
        assert len(run) == SIM_SCANS
        scans = run.read(0, len(run))
        returned = scans.ranges[~scans.no_return & ~scans.invalid]
        assert returned.size and returned.min() >= 0
        assert scans.invalid.any()


def test_range_noise_beyond_the_sensor_reach_is_refused_before_flying(no_flight, tmp_path, capsys):
    argv = ["simulate", "--scene", "boxes", "--scans", SIM_SCANS, "--range-noise", "1e6", "--out", tmp_path / "x.h5"]
    line = refused(capsys, argv)
    assert "--range-noise" in line and "11 m" in line
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------ 4. OctoMap import


def test_octomap_import_refuses_an_out_that_is_no_vog(global_vog, tmp_path, capsys):
    tree = tmp_path / "g.bt"
    assert cli.main(["export", str(global_vog), "--out", str(tree), "-q"]) == 0
    capsys.readouterr()
    for argv in ([tree], [tmp_path / "missing.bag", "--octomap", "/octomap"]):
        line = refused(capsys, ["import", *argv, "--out", tmp_path / "gmap.h5"])
        assert "--out" in line and ".vog" in line and "gmap.h5" in line
    assert not (tmp_path / "gmap.h5").exists()
    assert cli.main(["import", str(tree), "--out", str(tmp_path / "gmap.vog"), "-q"]) == 0
    assert vj.VoxelMap.load(tmp_path / "gmap.vog", device="cpu").voxels()[1].size > 0


# ------------------------------------------------------------------------------ 5. view


@pytest.fixture
def no_viewer(monkeypatch):
    """Spawning a viewer fails the test."""
    rerun = pytest.importorskip("rerun")

    def spawn(*args, **kwargs):
        raise AssertionError("a viewer was spawned")

    monkeypatch.setattr(rerun.RecordingStream, "spawn", spawn)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="X11/Wayland displays are Linux's")
def test_view_without_a_display_says_so_before_spawning(no_viewer, global_vog, monkeypatch, capsys):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    line = refused(capsys, ["view", global_vog])
    assert "no display" in line and "DISPLAY" in line and "--save FILE.rrd" in line and "PATH" not in line
    # a folder with no map is still what is named first (a missing path: test_cli_help's "view nope.vog")
    assert "no global_map.vog" in refused(capsys, ["view", global_vog.parent.parent])


@pytest.mark.parametrize(
    "error, hint",
    [
        ("gRPC has been unable to connect for 6s, uri: rerun+http://127.0.0.1:9876/proxy", False),
        ("Failed to find Rerun Viewer executable in PATH.\nYou can install binaries with cargo", True),
    ],
)
def test_view_hints_at_path_only_when_rerun_was_not_found(error, hint, global_vog, monkeypatch, capsys):
    def view(*args, **kwargs):
        raise RuntimeError(error)

    monkeypatch.setattr("vogjax.report.viewer.view", view)
    monkeypatch.setenv("DISPLAY", ":0")
    line = refused(capsys, ["view", global_vog])
    assert "cannot open the rerun viewer" in line and "--save FILE.rrd" in line
    assert ("on PATH" in line) == hint


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reaping reads /proc")
def test_a_failed_viewer_is_reaped(tmp_path):
    """A child named rerun that exited (spawned without a Popen to wait on it, as rerun does) is
    reaped: no defunct process is left."""
    fake = tmp_path / "rerun"
    fake.symlink_to("/bin/true")
    pid = os.posix_spawn(str(fake), [str(fake)], os.environ)
    deadline = time.monotonic() + 5
    while Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1].split()[0] != "Z":
        assert time.monotonic() < deadline, "the fake viewer did not exit"
        time.sleep(0.01)
    view_command.reap_viewers()
    assert not Path(f"/proc/{pid}").exists()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)


def test_lidar_range_noise_beyond_the_sensor_reach_is_refused_before_driving(tmp_path, capsys, monkeypatch):
    from vogjax.sim import lidar_mission

    def drive(*args, **kwargs):
        raise AssertionError("the route was driven before the refusal")

    monkeypatch.setattr(lidar_mission, "_scans", drive)
    argv = ["simulate", "--scene", "warehouse", "--scans", 5, "--range-noise", "1e6", "--out", tmp_path / "w.h5"]
    line = refused(capsys, argv)
    assert "--range-noise" in line and "50 m" in line
    assert not list(tmp_path.iterdir())


def test_scan_import_refuses_a_vog_out(tmp_path, capsys):
    """Scans import as a run (HDF5): under a .vog name, `view` and `export` took it for a map."""
    line = refused(capsys, ["import", tmp_path / "missing.bag", "--odometry", "/odom", "--out", tmp_path / "run.vog"])
    assert "--out" in line and "run.vog" in line
