"""`vogjax map` end to end on a small boxes survey flown twice, and its failure modes."""

import json

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli, pipeline
from vogjax.config import JobConfig
from vogjax.geometry import log_se3
from vogjax.io.dataset import DatasetWriter
from vogjax.report import job
from vogjax.sim import simulate_run

SETTINGS = """
[pipeline]
eps_rot = 0
eps_trans = 0
eps_cov = 0
eps_move_m = 0

[timing]
rays = 2000
every_submaps = 6

[report]
surface_points = 20000
"""


@pytest.fixture(scope="module")
def boxes_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "boxes.h5"
    simulate_run("boxes", path, laps=2, progress=False)
    return path


@pytest.fixture(scope="module")
def mapped(boxes_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    (out / "settings.toml").write_text(SETTINGS)
    assert (
        cli.main(["map", str(boxes_run), "--out", str(out / "maps"), "--config", str(out / "settings.toml"), "--quiet"])
        == 0
    )
    return out / "maps" / boxes_run.stem


def test_pipeline_closes_loops_and_beats_navigation(boxes_run):
    config = JobConfig.from_document(
        {"pipeline": {"eps_rot": 0, "eps_trans": 0, "eps_cov": 0, "eps_move_m": 0}}
    ).pipeline
    result = pipeline.run(boxes_run, config, progress=False)
    assert len(result.loop_closures) >= 3
    # closures agree with the true relative poses, in the directions they constrain, far
    # better than navigation does
    truth, nav = result.truth, result.navigation
    closure_errors, nav_errors = [], []
    for c in result.loop_closures:
        true_rel = np.linalg.inv(truth[c.i]) @ truth[c.k]
        basis = np.eye(6) if c.basis is None else c.basis
        for T, errors in ((c.T_i_k, closure_errors), (np.linalg.inv(nav[c.i]) @ nav[c.k], nav_errors)):
            errors.append(np.linalg.norm(basis.T @ log_se3(np.linalg.inv(true_rel) @ T)))
    assert max(closure_errors) < 0.4
    assert np.mean(closure_errors) < 0.5 * np.mean(nav_errors)
    error = lambda poses: np.sqrt(np.mean(np.sum((poses[:, :3, 3] - truth[:, :3, 3]) ** 2, axis=1)))
    assert error(result.optimized) < 0.6 * error(nav)
    metrics = result.metrics
    assert metrics["trajectory_rmse_m"]["optimized"] == pytest.approx(error(result.optimized))
    assert metrics["loop_closures"]["accepted"] == len(result.loop_closures)
    assert sum(metrics["loop_closures"]["rejected_by_reason"].values()) == len(result.rejected)
    # per scan too: scans carried with their submaps follow the truth better than navigation
    scan_error = lambda which: np.sqrt(
        np.mean(np.sum((result.scan_poses(which)[:, :3, 3] - result.scan_truth[:, :3, 3]) ** 2, axis=1))
    )
    assert scan_error("optimized") < scan_error("navigation")
    # with eps = 0 the online map is the full merge, bit for bit
    fresh = vj.GlobalMap(config.map)
    fresh.merge(result.vog)
    assert all(np.array_equal(a, b) for a, b in zip(result.global_map.sums(), fresh.sums()))


def test_map_writes_a_complete_report(mapped, boxes_run):
    report = json.loads((mapped / "report.json").read_text())
    assert report["run"] == str(boxes_run) and report["scene"] == "boxes"
    assert set(report["auc"]) == {"online", "virtual", "full_merge", "standard", "true_pose", "rigid_truth"}
    assert all(0.5 < v <= 1.0 for v in report["auc"].values())
    assert report["auc"]["online"] == report["auc"]["full_merge"]  # eps = 0: the same map
    assert abs(report["auc"]["online"] - report["auc"]["virtual"]) < 0.01
    assert set(report["rmse_m"]) == {"standard", "without_loop_closures", "with_loop_closures"}
    assert all(0 < v < 1.0 for v in report["rmse_m"].values())
    assert report["rmse_m"]["with_loop_closures"] < report["rmse_m"]["standard"]
    assert report["loop_closures"]["accepted"] >= 3
    assert report["trajectory_rmse_m"]["optimized"] < report["trajectory_rmse_m"]["navigation"]
    assert report["agreement"]["misclassified"] == 0
    timing = report["timing_s"]
    assert timing["scans_per_s"] > 0 and set(timing["steps"]) >= {"integration", "loop_closure", "isam2", "undo_redo"}
    curves = timing["curves"]
    assert len(curves["online_s"]) == report["submaps"] and curves["rays"] == 2000
    assert curves["sampled_submaps"][-1] == report["submaps"]
    assert report["config"]["pipeline"]["eps_cov"] == 0 and report["config"]["pipeline"]["timing"]["rays"] == 2000
    assert {"vogjax", "warp", "jax", "gtsam", "numpy"} <= set(report["versions"])
    # the map file holds the online map; the CSV one row per submap
    gmap = vj.GlobalMap.load(mapped / "global_map.vog")
    assert gmap.applied_ids == tuple(range(report["submaps"]))
    table = np.genfromtxt(mapped / "trajectories.csv", delimiter=",", names=True)
    assert len(table) == report["submaps"]
    for figure in ("top_view", "trajectory", "roc", "timing"):
        assert (mapped / f"{figure}.png").stat().st_size > 10_000
    assert not [p for p in mapped.parent.iterdir() if p.name.startswith(".")]  # no staging left


def test_a_failure_while_writing_leaves_the_earlier_results(mapped, boxes_run, monkeypatch):
    before = (mapped / "report.json").read_text()

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(job.plots, "timing", broken)
    config = JobConfig.from_document({"timing": {"rays": 100, "every_submaps": 5}, "report": {"surface_points": 1000}})
    with pytest.raises(RuntimeError, match="disk full"):
        job.map_runs([boxes_run], mapped.parent, config, progress=False, overwrite=True)
    assert (mapped / "report.json").read_text() == before
    assert sorted(p.name for p in mapped.parent.iterdir()) == [mapped.name]


def run_cli(capsys, *args):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["map", *map(str, args), "--quiet"])
    assert exit_info.value.code == 2
    return capsys.readouterr().err


def test_missing_and_corrupt_runs_are_clear_errors_with_no_output(boxes_run, tmp_path, capsys):
    out = tmp_path / "out"
    assert "does not exist" in run_cli(capsys, tmp_path / "nope.h5", "--out", out)
    corrupt = tmp_path / "corrupt.h5"
    corrupt.write_bytes(boxes_run.read_bytes()[:5000])
    assert "corrupt.h5" in run_cli(capsys, corrupt, "--out", out)
    empty = tmp_path / "empty.h5"
    with DatasetWriter(empty, 96, {"scene": "boxes"}):
        pass
    assert "holds no scans" in run_cli(capsys, empty, "--out", out)
    # one bad run among good ones: nothing is mapped
    assert "corrupt.h5" in run_cli(capsys, boxes_run, corrupt, "--out", out)
    assert not out.exists()


@pytest.mark.parametrize(
    "settings, message",
    [
        ("[map]\nvoxel_sise = 0.1\n", "unknown setting map.voxel_sise"),
        ("[maps]\nvoxel_size = 0.1\n", "unknown config table(s) maps"),
        ("[map]\nvoxel_size = 'small'\n", "map.voxel_size must be float"),
        ("[map]\nvoxel_size = -1.0\n", "voxel_size must be a positive number"),
        ("[pipeline]\neps_cov = 'big'\n", "eps_cov must be 'auto'"),
        ("[loop_closure.icp]\nmax_iterations = 2.5\n", "loop_closure.icp.max_iterations must be int"),
        ("[timing]\nrays = 0\n", "rays must be a positive integer"),
        ("[map\nvoxel_size = 0.1\n", "not valid TOML"),
    ],
)
def test_bad_settings_are_clear_errors_with_no_output(boxes_run, tmp_path, capsys, settings, message):
    (tmp_path / "bad.toml").write_text(settings)
    out = tmp_path / "out"
    assert message in run_cli(capsys, boxes_run, "--out", out, "--config", tmp_path / "bad.toml")
    assert not out.exists()


def test_settings_reach_the_configuration(tmp_path):
    (tmp_path / "s.toml").write_text(
        "[map]\nvoxel_size = 0.2\n[nav_noise]\nsigma2_x = 0.002\n"
        "[pipeline]\nscans_per_submap = 'covariance'\n"
        "[loop_closure.correlative]\nresolution_m = 0.15\n"
    )
    config = JobConfig.from_toml(tmp_path / "s.toml")
    assert config.pipeline.map.voxel_size == 0.2 and config.pipeline.map.prob_hit == vj.MapConfig().prob_hit
    assert config.pipeline.nav_noise.sigma2_x == 0.002
    assert config.pipeline.scans_per_submap is None
    assert config.pipeline.loop_closure.correlative.resolution_m == 0.15


def test_a_run_without_the_standard_map_reports_without_it(boxes_run, tmp_path, capsys):
    (tmp_path / "s.toml").write_text(
        "[pipeline]\nstandard_map = false\n[timing]\nevery_submaps = 0\n[report]\nsurface_points = 2000\n"
    )
    assert (
        cli.main(
            ["map", str(boxes_run), "--out", str(tmp_path / "out"), "--config", str(tmp_path / "s.toml"), "--quiet"]
        )
        == 0
    )
    report = json.loads((tmp_path / "out" / boxes_run.stem / "report.json").read_text())
    assert "standard" not in report["auc"] and report["auc"]["online"] > 0.5
    assert report["fig9"] is None and "update_per_submap" not in report["timing_s"]
    assert "boxes" in capsys.readouterr().out  # the summary table


def test_paper_preset_is_sodhi_with_the_bounded_rule(tmp_path):
    """`--preset paper` holds Sodhi et al.'s IV-C settings and keeps the half-voxel eps_move_m
    rule; a settings file setting it to 0 gives Algorithm 1 to the letter."""
    from vogjax.config import PipelineConfig

    paper = JobConfig.preset("paper").pipeline
    assert paper == PipelineConfig.paper()
    assert (paper.scans_per_submap, paper.eps_rot, paper.eps_trans, paper.eps_cov) == (200, 1e-2, 2e-3, "auto")
    m = paper.map
    assert (
        m.voxel_size,
        m.prob_hit,
        m.prob_miss,
        m.occupied_threshold,
        m.free_threshold,
        m.clamp_min,
        m.clamp_max,
    ) == (0.1, 0.75, 0.2, 0.7, 0.3, 0.0, 1.0)
    assert paper.eps_move_m == PipelineConfig().eps_move_m == 0.05
    settings = tmp_path / "literal.toml"
    settings.write_text("[pipeline]\neps_move_m = 0\n")
    literal = JobConfig.from_toml(settings, JobConfig.preset("paper")).pipeline
    assert literal == PipelineConfig.paper(eps_move_m=0.0) != paper


def test_every_report_field_is_described(mapped):
    from vogjax.report.fields import FIELDS, undescribed

    report = json.loads((mapped / "report.json").read_text())
    assert undescribed(report) == []
    # and every described field occurs (the confidence map's only with --crm, the recorded
    # odometry's error only with scan matching: tests/test_scan_matching.py)
    for path in FIELDS:
        if "*" in path or path.startswith("confidence_map.") or path == "trajectory_rmse_m.odometry":
            continue
        node = report
        for key in path.split("."):
            assert isinstance(node, dict) and key in node, f"{path} is described but not in the report"
            node = node[key]
    assert undescribed({"auc": {"online": 0.5}, "no_such_field": 1}) == ["no_such_field"]


def test_loop_closures_csv_and_report_give_every_verdict_and_its_figure(mapped):
    """One row per judged pair: accepted closures first (their error in the report), then each
    rejection with the reason, the figure that failed and its bound, which do fail (the figure
    past the bound on the side the test refuses)."""
    import csv

    report = json.loads((mapped / "report.json").read_text())
    with open(mapped / "loop_closures.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    lc = report["loop_closures"]
    assert len(rows) == lc["accepted"] + lc["rejected"]
    accepted, rejected = rows[: lc["accepted"]], rows[lc["accepted"] :]
    assert all(r["verdict"] == "accepted" for r in accepted)
    for row, error in zip(accepted, lc["errors"]):
        assert (int(row["i"]), int(row["k"])) == (error["i"], error["k"])
        assert float(row["error_m_rigid"]) == pytest.approx(error["translation_m_rigid"], abs=1e-6)
    lower_bounds = {"overlap", "inliers"}  # refused below the bound; the others above it
    assert [r["verdict"] for r in rejected] == [r["reason"] for r in lc["rejections"]]
    for row in rejected:
        if row["verdict"] == "not converged":
            continue
        value, limit = float(row["value"]), float(row["limit"])
        assert value < limit if row["verdict"] in lower_bounds else value > limit
    counts = {}
    for row in rejected:
        counts[row["verdict"]] = counts.get(row["verdict"], 0) + 1
    assert counts == lc["rejected_by_reason"]
