"""The batch pipeline end to end on a short simulated run of the boxes scene."""

import numpy as np
import pytest

import vogjax as vj
from vogjax import pipeline
from vogjax.report.files import save_trajectories
from vogjax.sim import simulate_run


@pytest.fixture(scope="module")
def boxes_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "boxes.h5"
    simulate_run("boxes", path, laps=1, num_scans=400, progress=False)
    return path


@pytest.fixture(scope="module")
def looping_boxes_run(tmp_path_factory):
    """500 scans of the boxes survey: since the beams within the sonar's blind distance of a box
    are invalid (they once gave "returns" from inside it), 400 scans hold no loop closure."""
    path = tmp_path_factory.mktemp("runs") / "boxes500.h5"
    simulate_run("boxes", path, laps=1, num_scans=500, progress=False)
    return path


def test_pipeline_keeps_the_online_map_equal_to_a_full_merge(boxes_run, tmp_path):
    config = pipeline.PipelineConfig(
        scans_per_submap=60, batch_scans=90, eps_rot=0.0, eps_trans=0.0, eps_move_m=0.0, eps_cov=0.0
    )
    result = pipeline.run(boxes_run, config, progress=False)
    # 400 scans cut every 60: six full submaps and a last one of 40, across batch boundaries
    assert result.vog.num_submaps == 7
    np.testing.assert_array_equal(result.submap_first_scan, np.arange(0, 400, 60))
    # submaps 1 and 4 straddle batches (90 scans each): each is integrated once, whole, in the
    # frame of its middle scan
    assert [result.vog.submap(i).revision for i in range(7)] == [1] * 7
    np.testing.assert_array_equal(result.submap_base_scan, np.r_[np.arange(30, 400, 60)[:6], 360 + 20])
    np.testing.assert_array_equal(result.navigation, result.scan_navigation[result.submap_base_scan])
    np.testing.assert_array_equal(result.optimized, result.vog.poses())
    assert result.global_map.applied_ids == tuple(range(7))
    fresh = vj.GlobalMap(config.map)
    fresh.merge(result.vog)
    a, b = result.global_map.sums(), fresh.sums()
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    # the standard map holds every scan at its navigation pose
    assert result.standard_map.voxels()[0].shape[0] > 10_000
    save_trajectories(result, tmp_path / "trajectories.csv")
    table = np.genfromtxt(tmp_path / "trajectories.csv", delimiter=",", names=True)
    assert len(table) == 7
    np.testing.assert_allclose(table["truth_x"], result.truth[:, 0, 3], atol=1e-6)


def test_run_evaluation_against_ground_truth(boxes_run):
    from vogjax import report as vj_eval
    from vogjax import scenes

    config = pipeline.PipelineConfig(scans_per_submap=80, eps_rot=0.0, eps_trans=0.0, eps_cov=0.0, eps_move_m=0.0)
    result = pipeline.run(boxes_run, config, progress=False)
    metrics, curves = vj_eval.evaluate_run(result, scenes.load("boxes"), surface_points=20_000)
    auc = metrics["auc"]
    # the online map, the virtual map at voxel centres and a full merge are the same map
    assert auc["online"] == auc["virtual"] == auc["full_merge"]
    assert metrics["agreement"]["misclassified"] == 0
    assert all(0.5 < value <= 1.0 for value in auc.values())  # better than chance (see README)
    assert all(0.0 < value < 0.3 for value in metrics["rmse_m"].values())
    assert curves["standard"].true_positive_rate[-1] == 1.0


def test_submaps_cut_by_the_covariance_bound(boxes_run):
    noise = vj.NavNoise()
    config = pipeline.PipelineConfig(
        scans_per_submap=None, max_xy_variance_m2=noise.sigma2_x * 30.0, max_yaw_variance_rad2=1.0
    )
    result = pipeline.run(boxes_run, config, progress=False)
    # 30 s of drift at 5 Hz: 150 scans per submap (the first scan of the next one crosses it)
    np.testing.assert_array_equal(result.submap_first_scan, [0, 151, 302])


def test_bad_pipeline_config():
    with pytest.raises(ValueError, match="scans_per_submap"):
        pipeline.PipelineConfig(scans_per_submap=1)
    with pytest.raises(ValueError, match="batch_scans"):
        pipeline.PipelineConfig(batch_scans=0)


def test_confidence_rich_map_beside_the_standard_one(boxes_run):
    from vogjax import report as vj_eval
    from vogjax import scenes

    config = pipeline.PipelineConfig(scans_per_submap=100, confidence_map=True)
    result = pipeline.run(boxes_run, config, progress=False)
    crm = result.confidence_map
    # the same scans at the same navigation poses as the standard map: the same voxels observed
    centres, _ = result.standard_map.voxels()
    assert crm.observed(centres).mean() > 0.95
    metrics, curves = vj_eval.evaluate_run(result, scenes.load("boxes"), surface_points=5_000)
    assert 0.5 < metrics["auc"]["confidence"] <= 1.0
    details = metrics["confidence_map"]
    # its means sit closer to the truth than the standard map's probabilities (Agha-mohammadi's claim)
    assert details["mean_error"] < details["standard_mean_error"]


def test_rigid_truth_is_the_least_squares_placement_of_a_bent_submap():
    """rigid_truth against its definition: the true rotation, and no translation puts the
    returns closer to their true places (perturbations of it, and the base's true pose, all do
    worse); unbent returns give back the base's true pose."""
    from scipy.spatial.transform import Rotation

    from vogjax.pipeline.mapper import rigid_truth

    rng = np.random.default_rng(3)
    true = rng.uniform(-3, 3, (400, 3))
    T_base = np.eye(4)
    T_base[:3, :3] = Rotation.from_euler("zyx", [0.4, 0.05, -0.02]).as_matrix()
    T_base[:3, 3] = [5.0, -2.0, 1.0]
    in_base = (true - T_base[:3, 3]) @ T_base[:3, :3]
    np.testing.assert_allclose(rigid_truth(in_base, in_base, T_base), T_base, atol=1e-12)
    bent = in_base + 0.05 * np.c_[in_base[:, 0] ** 2, np.sin(in_base[:, 1]), in_base[:, 0]]  # drift's bend

    def cost(T):  # squared distances in the world
        return np.sum((bent @ T[:3, :3].T + T[:3, 3] - true) ** 2)

    best = rigid_truth(bent, in_base, T_base)
    np.testing.assert_array_equal(best[:3, :3], T_base[:3, :3])
    assert cost(best) < cost(T_base)
    for _ in range(50):
        moved = best.copy()
        moved[:3, 3] += rng.normal(0, 1e-3, 3)
        assert cost(moved) > cost(best)
    np.testing.assert_array_equal(rigid_truth(bent[:0], in_base[:0], T_base), T_base)  # no returns


def test_closure_errors_against_true_and_rigid_poses(looping_boxes_run):
    """Both precisions count closures within 0.2 m and 1 degree of the relative pose their
    references give, in the directions each closure constrains (recomputed here directly)."""
    from vogjax.geometry import inverse, log_se3

    result = pipeline.run(looping_boxes_run, pipeline.PipelineConfig(scans_per_submap=50), progress=False)
    assert result.loop_closures, "the boxes run closes loops"
    report = result.closure_errors()
    rigid, truth = result.rigid_truth, result.truth
    assert rigid is not None and not np.allclose(rigid, truth)  # navigation drifts inside submaps
    for suffix, poses in (("", truth), ("_rigid", rigid)):
        good = []
        for c, e in zip(result.loop_closures, report["errors"]):
            twist = log_se3(inverse(inverse(poses[c.i]) @ poses[c.k]) @ c.T_i_k)
            basis = np.eye(6) if c.basis is None else c.basis
            assert e["translation_m" + suffix] == pytest.approx(np.linalg.norm((basis @ basis.T @ twist)[3:]))
            good.append(e["translation_m" + suffix] <= 0.2 and e["rotation_deg" + suffix] <= 1.0)
        assert report["precision" + suffix] == np.mean(good)
    metrics = result.metrics
    assert metrics["loop_closures"]["precision_rigid"] == report["precision_rigid"]
    # the ceiling: a registration that found every pair's rigid truths exactly scores it, and
    # is perfect against the rigid truths
    import dataclasses

    bends = np.array([e["translation_m_bend"] for e in report["errors"]])
    assert bends.max() > 1e-3  # the boxes run's submaps are bent too
    perfect = dataclasses.replace(
        result,
        loop_closures=tuple(
            dataclasses.replace(c, T_i_k=inverse(rigid[c.i]) @ rigid[c.k]) for c in result.loop_closures
        ),
    )
    for bound in (0.999 * bends.min(), float(bends.max())):  # below every bend, then above them all
        ideal, ceiling = perfect.closure_errors(max_translation_m=bound), result.closure_errors(max_translation_m=bound)
        assert ideal["precision_rigid"] == 1.0
        assert ideal["precision"] == ceiling["precision_ceiling"] == np.mean(bends <= bound)
    ideal = perfect.closure_errors()
    for e, perfect_error in zip(report["errors"], ideal["errors"]):
        assert perfect_error["translation_m"] == pytest.approx(e["translation_m_bend"], abs=1e-9)
        assert perfect_error["rotation_deg"] == pytest.approx(e["rotation_deg_bend"], abs=1e-7)
        assert perfect_error["translation_m_rigid"] < 1e-9
    # without rigid truths there is no ceiling; without closures every precision is NaN
    no_rigid = dataclasses.replace(
        result, submaps=tuple(dataclasses.replace(r, T_world_base_rigid=None) for r in result.submaps)
    )
    assert set(no_rigid.closure_errors()) == {"precision", "errors"}
    assert "translation_m_bend" not in no_rigid.closure_errors()["errors"][0]
    empty = dataclasses.replace(result, loop_closures=())
    assert all(np.isnan(empty.closure_errors()[k]) for k in ("precision", "precision_rigid", "precision_ceiling"))
    # each rigid truth from the submap's own returns: in its frame by navigation, and by the truth
    from vogjax.io.dataset import Dataset
    from vogjax.pipeline.mapper import rigid_truth as fit

    with Dataset(looping_boxes_run) as run:
        for k in (0, len(result.submaps) // 2):
            s = result.submaps[k]
            scans = run.read(s.first_scan, s.first_scan + s.scans)
            base = scans.pose_nav[s.base_scan - s.first_scan]
            built = scans.world(np.linalg.inv(base) @ scans.pose_nav, 1e9)[1][scans.returned]
            true = scans.world(np.linalg.inv(truth[k]) @ scans.pose_truth, 1e9)[1][scans.returned]
            np.testing.assert_allclose(rigid[k], fit(built, true, truth[k]), atol=1e-9)
    assert metrics["trajectory_rmse_m"]["rigid_truth"] > 0
    # the aligned errors: the least RMS error over every turn about z (a 0.05 degree grid) with
    # its best x-y shift, z left as it is; never above the absolute error
    for name, poses in (("navigation", result.navigation), ("optimized", result.optimized)):
        p, q = poses[:, :3, 3], truth[:, :3, 3]
        best = np.inf
        for yaw in np.linspace(-np.pi, np.pi, 7201):
            c, s = np.cos(yaw), np.sin(yaw)
            turned = p[:, :2] @ np.array([[c, -s], [s, c]]).T
            offsets = turned + (q[:, :2].mean(axis=0) - turned.mean(axis=0)) - q[:, :2]
            best = min(best, np.sqrt(np.mean(np.sum(offsets**2, axis=1) + (p[:, 2] - q[:, 2]) ** 2)))
        aligned = metrics["trajectory_rmse_m"][name + "_aligned"]
        assert aligned <= best + 1e-9 and best <= aligned + 1e-3
        assert aligned <= metrics["trajectory_rmse_m"][name] + 1e-12


def test_rigid_truth_map_scores_the_true_pose_map_without_drift(tmp_path):
    """With (almost) no navigation drift the submaps are not bent and sit where the truth puts
    them: the rigid-truth map scores what the true-pose map scores."""
    from vogjax import report as vj_eval
    from vogjax import scenes

    still = vj.NavNoise(
        **{name: 1e-14 for name in ("sigma2_x", "sigma2_y", "sigma2_z", "sigma2_yaw", "sigma2_pitch", "sigma2_roll")}
    )
    path = tmp_path / "still.h5"
    simulate_run("boxes", path, laps=1, num_scans=240, noise=still, progress=False)
    config = pipeline.PipelineConfig(scans_per_submap=60, nav_noise=still)
    result = pipeline.run(path, config, progress=False)
    auc = vj_eval.evaluate_run(result, scenes.load("boxes"), surface_points=5_000)[0]["auc"]
    assert np.max(np.abs(result.rigid_truth[:, :3, 3] - result.truth[:, :3, 3])) < 1e-4
    assert auc["rigid_truth"] == pytest.approx(auc["true_pose"], abs=2e-3)


def test_aligned_auc_takes_out_where_the_anchor_put_the_map(boxes_run):
    """Registered to the truth, the maps score the same wherever the graph's anchor put them:
    the run moved as a whole by a quarter turn about z and a whole number of voxels (a motion
    that maps the voxel grid onto itself, so the moved maps are the same maps, moved) loses its
    plain AUC and keeps its aligned one."""
    import dataclasses

    from vogjax import report as vj_eval
    from vogjax import scenes

    # every eps zero: the online map is a full merge, so the voxels scored are the same both ways
    config = pipeline.PipelineConfig(scans_per_submap=100, eps_rot=0.0, eps_trans=0.0, eps_cov=0.0, eps_move_m=0.0)
    result = pipeline.run(boxes_run, config, progress=False)
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    turn[:3, 3] = np.array([12, -7, 0]) * config.map.voxel_size
    poses = turn @ result.optimized
    vog = result.vog.view(poses=poses)
    online = vj.GlobalMap(config.map)
    online.merge(vog)
    moved = dataclasses.replace(result, vog=vog, global_map=online, optimized=poses)
    scene = scenes.load("boxes")
    before = vj_eval.evaluate_run(result, scene, surface_points=5_000)[0]
    after = vj_eval.evaluate_run(moved, scene, surface_points=5_000)[0]
    assert after["auc"]["full_merge"] < before["auc"]["full_merge"] - 0.03
    for name in ("online", "virtual", "full_merge", "true_pose", "rigid_truth"):
        assert after["auc_aligned"][name] == pytest.approx(before["auc_aligned"][name], abs=1e-6)
    # the true-pose submaps placed by the truth, all turned: registered, they score what the
    # true-pose map scores where it is
    truth = turn @ result.truth
    placed = result.truth_vog.view(poses=truth)
    merged = vj.GlobalMap(config.map)
    merged.merge(placed)
    perfect = dataclasses.replace(result, vog=placed, global_map=merged, optimized=truth)
    scored = vj_eval.evaluate_run(perfect, scene, surface_points=5_000)[0]["auc_aligned"]
    assert scored["full_merge"] == pytest.approx(scored["true_pose"], abs=1e-6)
    # the registered online map's ROC goes to the figure, not among the maps as they stand
    metrics, curves = vj_eval.evaluate_run(moved, scene, surface_points=5_000)
    assert curves["online, registered to the truth"].auc == after["auc_aligned"]["online"]
    assert set(metrics["auc"]) == set(curves) - {"online, registered to the truth"}


def test_slam_on_a_second_thread_gives_the_same_bits(looping_boxes_run):
    """SLAM beside the map work (slam_thread) against every step in order: the same closures and
    rejections, optimised poses, global map sums and timing probes' submap counts."""
    import dataclasses

    config = pipeline.PipelineConfig(
        scans_per_submap=50, batch_scans=120, timing=pipeline.PipelineConfig().timing.replace(every_submaps=3)
    )
    one, two = (
        pipeline.run(looping_boxes_run, config.replace(slam_thread=flag), progress=False) for flag in ("off", "on")
    )
    assert one.loop_closures and one.rejected  # the graph moves, and some pairs are refused
    assert (one.slam_on_second_thread, two.slam_on_second_thread) == (False, True)
    np.testing.assert_array_equal(one.optimized, two.optimized)
    assert [(c.i, c.k) for c in one.loop_closures] == [(c.i, c.k) for c in two.loop_closures]
    for a, b in zip(one.loop_closures, two.loop_closures):
        assert np.array_equal(a.T_i_k, b.T_i_k) and np.array_equal(a.covariance, b.covariance)
    assert [dataclasses.astuple(r)[:3] for r in one.rejected] == [dataclasses.astuple(r)[:3] for r in two.rejected]
    assert all(np.array_equal(x, y) for x, y in zip(one.global_map.sums(), two.global_map.sums()))
    assert one.global_map.applied_ids == two.global_map.applied_ids
    assert [p["submaps"] for p in one.probes] == [p["submaps"] for p in two.probes]
    assert one.timings["reapplied"] == two.timings["reapplied"]


def test_auto_puts_slam_on_a_second_thread_where_a_second_core_can_take_it(monkeypatch):
    """slam_thread "auto": on with two or more usable CPU cores (or with the maps on CUDA), off
    on one; the usable cores are the process's affinity where the system tells it; "on" and
    "off" as they say."""
    import os
    import sys

    from vogjax.maps import parallel

    run_module = sys.modules["vogjax.pipeline.run"]
    config = pipeline.PipelineConfig()
    on_cuda = vj.devices.resolve(None).is_cuda
    for cores, expected in ((1, on_cuda), (2, True), (16, True)):
        monkeypatch.setattr(parallel, "usable_cores", lambda cores=cores: cores)
        assert run_module._overlap(config) is expected
        assert run_module._overlap(config.replace(slam_thread="on")) is True
        assert run_module._overlap(config.replace(slam_thread="off")) is False
    monkeypatch.undo()
    if hasattr(os, "sched_getaffinity") and not hasattr(os, "process_cpu_count"):
        monkeypatch.setattr(os, "cpu_count", lambda: 64)
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})  # taskset -c 3 on a big machine
        assert parallel.usable_cores() == 1
        assert run_module._overlap(config) is on_cuda


def test_an_interrupt_does_not_wait_for_the_slam_step_in_flight(boxes_run, monkeypatch):
    """With SLAM on the second thread, an error or Ctrl-C in the map work surfaces while the
    SLAM step in flight is still running, and that step never enters the maps."""
    import threading

    from vogjax.pipeline.mapper import Mapper

    release, running, taken = threading.Event(), threading.Event(), []
    slam, add = Mapper._slam, Mapper.add

    def slow_slam(self, *args):
        running.set()
        release.wait(30)  # held until the test has seen the interrupt
        return slam(self, *args)

    def interrupted_add(self, batch):
        add(self, batch)
        if running.wait(30):
            raise KeyboardInterrupt

    monkeypatch.setattr(Mapper, "_slam", slow_slam)
    monkeypatch.setattr(Mapper, "add", interrupted_add)
    monkeypatch.setattr(Mapper, "_take_slam", lambda self, *args: taken.append(args))
    # the first batch closes one submap, whose SLAM step is then in flight
    config = pipeline.PipelineConfig(scans_per_submap=50, batch_scans=60, slam_thread="on")
    with pytest.raises(KeyboardInterrupt):
        pipeline.run(boxes_run, config, progress=False)
    still_running = not release.is_set()
    release.set()
    assert running.is_set() and still_running and taken == []


def test_a_live_mapper_with_a_slam_thread_syncs_before_answering(boxes_run):
    """Between batches the last submap's SLAM may be in flight; sync() brings the graph and the
    global map up to date, as a mapper without the thread has them after each batch."""
    from vogjax.io.dataset import Dataset

    config = pipeline.PipelineConfig(scans_per_submap=50, batch_scans=120)
    with Dataset(boxes_run) as ds:
        plain, threaded = pipeline.Mapper(config, ds.metadata), pipeline.Mapper(config, ds.metadata, overlap=True)
        try:
            for batch in ds.batches(120):
                plain.add(batch)
                threaded.add(batch)
                threaded.sync()
                assert threaded.global_map.applied_ids == plain.global_map.applied_ids
                np.testing.assert_array_equal(threaded.vog.poses(), plain.vog.poses())
        finally:
            threaded.close()
