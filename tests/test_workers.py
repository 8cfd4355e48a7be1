"""`vogjax map --workers`: runs mapped in parallel by Ray give the reports and maps they give one
by one, and a run that fails fails alone."""

import json
import sys

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.sim import simulate_run

pytest.importorskip("ray")

SETTINGS = """
[pipeline]
eps_rot = 0
eps_trans = 0
eps_cov = 0

[timing]
every_submaps = 0

[report]
surface_points = 2000
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("workers")
    paths = [root / f"boxes_{seed}.h5" for seed in (0, 1)]
    for seed, path in enumerate(paths):
        simulate_run("boxes", path, laps=1, seed=seed, progress=False)
    (root / "settings.toml").write_text(SETTINGS)
    return root, paths


# every report entry that does not depend on wall time
COMPARED = (
    "run",
    "scene",
    "scans",
    "duration_s",
    "submaps",
    "auc",
    "rmse_m",
    "agreement",
    "trajectory_rmse_m",
    "loop_closures",
    "config",
    "device",
)


def without_wall_time(report):
    assert set(COMPARED) <= set(report)
    return {k: report[k] for k in COMPARED}


def test_two_workers_give_the_reports_of_one_by_one_and_a_failure_stays_alone(runs, capsys):
    root, paths = runs
    settings = str(root / "settings.toml")
    assert cli.main(["map", *map(str, paths), "--out", str(root / "serial"), "--config", settings, "--quiet"]) == 0
    broken = root / "broken.h5"
    broken.write_bytes(paths[0].read_bytes()[:4000])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        cli.main(
            [
                "map",
                str(paths[0]),
                str(broken),
                str(paths[1]),
                "--out",
                str(root / "parallel"),
                "--config",
                settings,
                "--workers",
                "2",
                "--quiet",
            ]
        )
    assert exit_info.value.code == 2
    captured = capsys.readouterr()
    errors = captured.err.strip().splitlines()
    assert len(errors) == 1 and errors[0].startswith(f"vogjax map: error: {broken}: ")
    assert not captured.out.startswith("20")  # no Ray banner before the table
    assert captured.out.splitlines()[0].split() == [p.stem for p in paths]  # the table's header: the runs
    for path in paths:
        serial = json.loads((root / "serial" / path.stem / "report.json").read_text())
        parallel = json.loads((root / "parallel" / path.stem / "report.json").read_text())
        assert serial["submaps"] >= 5 and serial["auc"]["online"] is not None
        assert without_wall_time(parallel) == without_wall_time(serial)
        a = vj.GlobalMap.load(root / "serial" / path.stem / "global_map.vog").sums()
        b = vj.GlobalMap.load(root / "parallel" / path.stem / "global_map.vog").sums()
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
        assert (root / "serial" / path.stem / "trajectories.csv").read_bytes() == (
            root / "parallel" / path.stem / "trajectories.csv"
        ).read_bytes()
    assert sorted(p.name for p in (root / "parallel").iterdir()) == sorted(p.stem for p in paths)


def test_bad_worker_arguments_are_clear_errors(runs, capsys, monkeypatch):
    root, paths = runs

    def fails(*extra):
        with pytest.raises(SystemExit) as exit_info:
            cli.main(["map", str(paths[0]), "--out", str(root / "bad"), "--quiet", *extra])
        assert exit_info.value.code == 2
        return capsys.readouterr().err

    assert "argument --workers: must be a positive integer" in fails("--workers", "0")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    assert "pip install 'vogjax[workers]'" in fails("--workers", "2")
    assert not (root / "bad").exists()
