"""The commands behave as the README and their --help say: `vogjax view` without a viewer on
PATH, `vogjax import` and an existing --out, the tables `vogjax explore --config` takes."""

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli


def refused(capsys, argv) -> str:
    """The one stderr line of a command refused with exit 2."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main([str(a) for a in argv])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_view_without_a_viewer_on_path_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    rerun = pytest.importorskip("rerun")
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=5.0), device="cpu")
    vmap.integrate_scan(np.zeros(3), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    vmap.save(tmp_path / "map.vog")

    def spawn(self, *args, **kwargs):  # what rerun raises when `rerun` is not on PATH
        raise RuntimeError("Failed to find Rerun Viewer executable in PATH.")

    monkeypatch.setattr(rerun.RecordingStream, "spawn", spawn)
    monkeypatch.setenv("DISPLAY", ":0")  # a display, so the viewer is what fails
    line = refused(capsys, ["view", tmp_path / "map.vog"])
    assert line.startswith("vogjax view: error: cannot open the rerun viewer")
    assert "Failed to find Rerun Viewer executable in PATH" in line
    assert "--save FILE.rrd" in line and "on PATH" in line
    # --save never spawns a viewer: the same call with it still works
    assert cli.main(["view", str(tmp_path / "map.vog"), "--save", str(tmp_path / "map.rrd")]) == 0
    assert (tmp_path / "map.rrd").stat().st_size > 0


def test_view_passes_other_runtime_errors_through(tmp_path, monkeypatch):
    rerun = pytest.importorskip("rerun")
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=5.0), device="cpu")
    vmap.save(tmp_path / "map.vog")

    def spawn(self, *args, **kwargs):
        raise RuntimeError("something else")

    monkeypatch.setattr(rerun.RecordingStream, "spawn", spawn)
    monkeypatch.setenv("DISPLAY", ":0")
    with pytest.raises(RuntimeError, match="something else"):
        cli.main(["view", str(tmp_path / "map.vog")])


def test_import_keeps_an_existing_run_unless_overwrite(tmp_path, capsys):
    pytest.importorskip("rosbags")
    from tests.test_import import cloud_bag

    bag, _, _ = cloud_bag(tmp_path / "run.bag", "ros1", scans=6)
    out = tmp_path / "run.h5"
    out.write_bytes(b"an earlier run")
    argv = ["import", bag, "--points", "/points", "--odometry", "/odom", "--frame", "lidar", "--out", out, "--quiet"]
    line = refused(capsys, argv)
    assert line.startswith("vogjax import: error: --out ") and str(out) in line and "--overwrite" in line
    assert out.read_bytes() == b"an earlier run"  # refused before any work
    assert cli.main([str(a) for a in argv] + ["--overwrite"]) == 0
    assert str(out) in capsys.readouterr().out
    from vogjax.io.dataset import Dataset

    with Dataset(out) as ds:
        assert len(ds) > 0


def test_explore_config_takes_the_tables_its_help_names(tmp_path, capsys):
    from vogjax.sim.explore import load_settings

    with pytest.raises(SystemExit):
        cli.main(["explore", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    tables = [
        "[planner]",
        "[map]",
        "[nav_noise]",
        "[loop_closure]",
        "[loop_closure.icp]",
        "[loop_closure.correlative]",
        "[timing]",
        "[pipeline]",
    ]
    for table in tables:
        assert table in help_text
    assert "not [report]" in help_text
    settings = tmp_path / "s.toml"
    settings.write_text(
        "[planner]\nedge_length_m = 1.5\n[map]\nvoxel_size = 0.2\n[nav_noise]\n"
        "[loop_closure.icp]\nmax_iterations = 7\n[loop_closure.correlative]\nresolution_m = 0.3\n"
        "[timing]\nevery_submaps = 0\n[pipeline]\nscans_per_submap = 50\n"
    )
    planner, pipeline = load_settings(settings, "boxes", 0)
    assert planner.edge_length_m == 1.5 and pipeline.map.voxel_size == 0.2
    assert pipeline.loop_closure.icp.max_iterations == 7 and pipeline.loop_closure.correlative.resolution_m == 0.3
    assert pipeline.timing.every_submaps == 0 and pipeline.scans_per_submap == 50
    settings.write_text("[report]\nsurface_points = 2000\n")
    with pytest.raises(ValueError, match="unknown config table"):
        load_settings(settings, "boxes", 0)
