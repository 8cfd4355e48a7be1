"""`vogjax view --save`: a report folder logged headless into an .rrd, read back with rerun's
own chunk reader: every entity there, holding what the folder holds."""

import sys
from collections import defaultdict

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.sim import simulate_run

rerun = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

SETTINGS = """
[pipeline]
scans_per_submap = 60

[timing]
every_submaps = 3
rays = 500

[report]
surface_points = 2000
"""
CLOSURES = [(0, 3), (1, 4), (2, 5)]


@pytest.fixture(scope="module")
def report_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    run = root / "boxes.h5"
    simulate_run("boxes", run, laps=1, num_scans=400, progress=False)
    (root / "settings.toml").write_text(SETTINGS)
    assert (
        cli.main(["map", str(run), "--out", str(root / "maps"), "--config", str(root / "settings.toml"), "--quiet"])
        == 0
    )
    folder = root / "maps" / "boxes"
    # what `vogjax map` is to write beside trajectories.csv: one row per accepted closure
    (folder / "loop_closures.csv").write_text("i,k\n" + "".join(f"{i},{k}\n" for i, k in CLOSURES))
    return folder


def entities(path):
    """entity path -> {column: [values of every row, in log order]} and whether static."""
    rows = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name == "log_time":  # wall clock
                continue
            rows[chunk.entity_path][name] += batch.column(name).to_pylist()
    return rows


def test_a_report_folder_lands_in_the_recording(report_folder, tmp_path, capsys):
    out = tmp_path / "boxes.rrd"
    assert cli.main(["view", str(report_folder), "--save", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    logged = entities(out)
    # the map: every occupied voxel of the global map, one box each, coloured
    gmap = vj.GlobalMap.load(report_folder / "global_map.vog")
    centres, values = gmap.voxels()
    occupied = centres[gmap.state(centres) == vj.OCCUPIED]
    boxes = logged["/map/occupied"]
    np.testing.assert_allclose(np.array(boxes["Boxes3D:centers"][0]), occupied, atol=1e-6)
    assert len(boxes["Boxes3D:colors"][0]) == len(occupied)
    assert boxes["Boxes3D:half_sizes"][0][0] == pytest.approx([gmap.config.voxel_size / 2] * 3)
    # trajectories grow one submap per step of the submap timeline
    table = np.genfromtxt(report_folder / "trajectories.csv", delimiter=",", names=True)
    submaps = len(table)
    assert submaps >= 6
    for name in ("navigation", "optimized", "truth"):
        strips = logged[f"/trajectory/{name}"]
        assert strips["submap"] == list(range(submaps))
        assert strips["scan"] == table["first_scan"].astype(int).tolist()
        expected = np.stack([table[f"{name}_{axis}"] for axis in "xyz"], axis=1)
        np.testing.assert_allclose(np.array(strips["LineStrips3D:strips"][-1][0]), expected, atol=1e-5)
        assert [len(s[0]) for s in strips["LineStrips3D:strips"]] == list(range(1, submaps + 1))
    # loop closures: lines between optimised bases, each from its later submap on
    optimized = np.stack([table[f"optimized_{axis}"] for axis in "xyz"], axis=1)
    lines = logged["/loop_closures"]["LineStrips3D:strips"]
    np.testing.assert_allclose(np.array(lines[-1]), optimized[np.array(CLOSURES)], atol=1e-5)
    assert [len(step) for step in lines] == [sum(k <= s for _, k in CLOSURES) for s in range(submaps)]
    # per-submap update times from the report, and the report itself
    assert len(logged["/timing/online_update_ms"]["Scalars:scalars"]) == submaps
    assert logged["/report"]["TextDocument:text"][0][0].startswith("# boxes\n")


def test_a_map_file_alone_and_a_folder_of_runs(report_folder, tmp_path):
    from vogjax.report.viewer import view

    logged = view(report_folder / "global_map.vog", save=tmp_path / "map.rrd")
    assert list(logged) == ["map/occupied"]
    assert len(entities(tmp_path / "map.rrd")["/map/occupied"]["Boxes3D:centers"][0]) == logged["map/occupied"]
    logged = view(report_folder.parent, save=tmp_path / "runs.rrd")  # DIR of `vogjax map`: each run by name
    assert "boxes/map/occupied" in logged and "/boxes/trajectory/optimized" in entities(tmp_path / "runs.rrd")


def test_errors_are_clear(report_folder, tmp_path, capsys, monkeypatch):
    def fails(*args):
        with pytest.raises(SystemExit) as exit_info:
            cli.main(["view", *map(str, args)])
        assert exit_info.value.code == 2
        return capsys.readouterr().err

    assert "does not exist" in fails(tmp_path / "nothing", "--save", tmp_path / "x.rrd")
    assert "no global_map.vog" in fails(tmp_path, "--save", tmp_path / "x.rrd")
    assert "--save must name an .rrd file" in fails(report_folder, "--save", tmp_path / "x.txt")
    monkeypatch.setitem(sys.modules, "rerun", None)  # as if the extra were not installed
    assert "pip install 'vogjax[view]'" in fails(report_folder, "--save", tmp_path / "x.rrd")
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*tmp"))
