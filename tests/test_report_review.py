"""From a review of the report: the online map's agreement with the full merge over every voxel
either observed, the report `map_run` returns equal to the one it writes, and a bad settings
file named in its refusal. Each case failed on the code before it."""

import json

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.report.evaluate import _agreement

from .test_job import boxes_run  # noqa: F401 (a fixture)


def test_agreement_counts_every_voxel_either_map_observed():
    """Brute force: the union of both maps' voxel keys, their states compared one by one. The
    maps differ far outside any truth box too (the report compared the truth's voxels only)."""
    config = vj.MapConfig(voxel_size=0.1, max_range=20.0)
    rng = np.random.default_rng(0)
    a, b = vj.VoxelMap(config, device="cpu"), vj.VoxelMap(config, device="cpu")
    origin = np.array([0.05, 0.05, 0.05])
    shared = rng.uniform(-3, 3, (200, 3))
    a.integrate_scan(origin, shared)
    b.integrate_scan(origin, shared)
    a.integrate_scan(origin, rng.uniform(5, 9, (50, 3)))  # only a saw these
    b.integrate_scan(origin + 1.0, rng.uniform(-9, -5, (50, 3)))  # only b these
    keys = {tuple(k) for m in (a, b) for k in np.floor(m.voxels()[0] / 0.1).astype(np.int64)}
    centres = (np.array(sorted(keys)) + 0.5) * 0.1
    states_a, states_b = a.state(centres), b.state(centres)
    expected = {
        "voxels": len(keys),
        "misclassified": int(np.sum(states_a != states_b)),
        "occupied_disagreements": int(
            np.sum((states_a != states_b) & ((states_a == vj.OCCUPIED) | (states_b == vj.OCCUPIED)))
        ),
    }
    assert _agreement(a, b, 0.1) == expected and expected["misclassified"] > 100
    assert _agreement(a, a, 0.1)["misclassified"] == 0


def test_the_report_map_returns_is_the_one_it_writes(boxes_run, tmp_path):  # noqa: F811
    """Undefined figures (no closure to score, say) were NaN in the returned report and in the
    table `vogjax map` prints, and null in report.json."""
    from vogjax.config import JobConfig
    from vogjax.report import document, job

    config = JobConfig.from_document({"loop_closure": {"max_candidates": 0}, "report": {"surface_points": 2000}})
    (report,) = job.map_runs([boxes_run], tmp_path / "maps", config, progress=False)
    written = json.loads((tmp_path / "maps" / boxes_run.stem / "report.json").read_text())
    assert report["loop_closures"]["precision"] is None
    # strict JSON (no NaN) and the file's very content
    assert json.loads(json.dumps(report, default=document.json_default, allow_nan=False)) == written


@pytest.mark.parametrize("command", ["map", "explore"])
def test_a_bad_settings_file_is_named_in_the_refusal(tmp_path, capsys, command, boxes_run):  # noqa: F811
    bad = tmp_path / "bad.toml"
    bad.write_text("[map]\nvoxel_sise = 0.1\n")
    arguments = (
        [str(boxes_run), "--out", str(tmp_path / "out")]
        if command == "map"
        else ["--scene", "tank", "--submaps", "2", "--out", str(tmp_path / "e")]
    )
    with pytest.raises(SystemExit) as stop:
        cli.main([command, *arguments, "--config", str(bad), "-q"])
    assert stop.value.code == 2
    error = capsys.readouterr().err.strip()
    assert str(bad) in error and "voxel_sise" in error and len(error.splitlines()) == 1
