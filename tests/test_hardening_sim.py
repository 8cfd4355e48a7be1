"""Simulation, scenes, metrics and geometry inputs a review found accepted, crashing or answered
wrongly, each pinned down: a ValueError naming the argument, raised before anything changes, or
the right answer."""

from __future__ import annotations

import numpy as np
import pytest

import vogjax as vj
from vogjax import geometry, scenes, sim
from vogjax import report as vj_eval
from vogjax.geometry import pose_from_xyz_yaw
from vogjax.scenes.scene import MAX_GROUND_TRUTH_CELLS
from vogjax.sensors import ProfilingSonar
from vogjax.sim import vehicle
from vogjax.sim.explore import explore
from vogjax.sim.mission import MAX_SCANS, mission_scans

SONAR = vj.SonarConfig(beams=8)


# ------------------------------------------------------------------ A. scan rates and physics steps


@pytest.mark.parametrize("rate", [15.0, 30.0, 6.6, 1e6])
def test_sim_rates_off_the_physics_step_are_refused_before_any_work(tmp_path, rate):
    """A scan comes after whole 0.05 s steps: 15 Hz would record 0.067 s between scans 0.05 s of
    physics apart (a vehicle flying 1.33x its speed limit)."""
    out = tmp_path / "run.h5"
    with pytest.raises(ValueError, match=r"sensor\.rate_hz must be 20/n Hz"):
        sim.simulate_run("boxes", out, num_scans=5, sensor=vj.SonarConfig(rate_hz=rate, beams=4), progress=False)
    with pytest.raises(ValueError, match=r"sensor\.rate_hz"):
        explore("boxes", tmp_path / "explored.h5", 1, sensor=vj.SonarConfig(rate_hz=rate), progress=False)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="scan_rate_hz must be 20/n Hz"):
        sim.simulate(pose_from_xyz_yaw(0, 0, 1, 0), [[1.0, 0.0, 1.0, 0.0]], 3, scan_rate_hz=rate)


def test_rates_of_whole_physics_steps_are_accepted():
    assert [vehicle.steps_per_scan(rate) for rate in (20.0, 10.0, 20 / 3, 5.0, 4.0, 0.5)] == [1, 2, 3, 4, 5, 40]
    with pytest.raises(ValueError, match="scan_rate_hz must be at least"):
        vehicle.steps_per_scan(1e-9)


def test_mission_scans_are_bounded_by_max_scans():
    scene = scenes.load("boxes")
    assert mission_scans(scene.survey(2), scene.start_pose, 5.0) < MAX_SCANS
    with pytest.raises(ValueError, match=f"more than the limit of {MAX_SCANS}"):
        mission_scans(scene.survey(2), scene.start_pose, 1e6)


# ------------------------------------------------------------------ B. sim's public functions

START = pose_from_xyz_yaw(0.0, 0.0, 1.0, 0.0)
WAYPOINTS = np.array([[1.0, 0.0, 1.0, 0.0], [1.0, 1.0, 1.0, 0.5]])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"scan_rate_hz": 0.0}, "scan_rate_hz must be a positive number"),
        ({"scan_rate_hz": -5.0}, "scan_rate_hz must be a positive number"),
        ({"scan_rate_hz": float("nan")}, "scan_rate_hz"),
        ({"waypoints": np.full((1, 4), np.nan)}, "waypoints contains NaN"),
        ({"waypoints": np.zeros((0, 4))}, "waypoints must hold at least one waypoint"),
        ({"waypoints": np.zeros((2, 3))}, r"waypoints must have shape \(N, 4\)"),
        ({"waypoints": [[1e30, 0.0, 1.0, 0.0]]}, "waypoints must lie within"),
        ({"num_scans": -1}, "num_scans"),
        ({"num_scans": 2.5}, "num_scans"),
        ({"num_scans": MAX_SCANS + 1}, "num_scans"),
        ({"start_pose": np.full((4, 4), np.nan)}, "start_pose contains NaN"),
        ({"start_pose": np.diag([2.0, 2.0, 2.0, 1.0])}, "start_pose is not rigid"),
        ({"start_pose": np.eye(3)}, "start_pose must have shape"),
        ({"config": {"max_speed_mps": 1.0}}, "config must be a ControllerConfig"),
    ],
)
def test_simulate_checks_its_arguments(kwargs, message):
    args = {"start_pose": START, "waypoints": WAYPOINTS, "num_scans": 3, **kwargs}
    with pytest.raises(ValueError, match=message):
        sim.simulate(**args)


def test_simulate_batch_checks_its_arguments():
    starts = np.stack([START, START])
    with pytest.raises(ValueError, match="waypoints must have shape"):
        sim.simulate_batch(starts, WAYPOINTS, 3)
    with pytest.raises(ValueError, match="start_poses must hold at least one pose"):
        sim.simulate_batch(np.zeros((0, 4, 4)), np.zeros((0, 2, 4)), 3)
    with pytest.raises(ValueError, match="scan_rate_hz"):
        sim.simulate_batch(starts, np.stack([WAYPOINTS, WAYPOINTS]), 3, scan_rate_hz=0.0)


def test_scan_checks_its_poses():
    scene = scenes.load("boxes")
    T = scene.start_pose @ ProfilingSonar(SONAR).T_vehicle_sensor
    nan = T.copy()
    nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="T_world_sensor contains NaN"):  # was: no return on every beam
        sim.scan(scene.warp_mesh, nan[None], SONAR)
    scaled = T.copy()
    scaled[:3, :3] *= 2
    with pytest.raises(ValueError, match="T_world_sensor is not rigid"):  # was: every range halved
        sim.scan(scene.warp_mesh, scaled[None], SONAR)
    for shape in [(3, 3), (5, 5), (2, 16)]:
        with pytest.raises(ValueError, match="T_world_sensor must have shape"):
            sim.scan(scene.warp_mesh, np.zeros(shape), SONAR)
    with pytest.raises(ValueError, match="mesh must be a warp.Mesh"):
        sim.scan(scene.mesh, T, SONAR)
    assert sim.scan(scene.warp_mesh, T, SONAR).ranges.shape == (1, 8)  # one (4,4) pose as before


def test_drifting_navigation_checks_its_arguments():
    truth = np.tile(np.eye(4), (4, 1, 1))
    truth[:, 0, 3] = np.arange(4)
    for times, message in [
        ([0.0, 1.0, 0.5, 0.2], "times_s must not decrease"),
        ([0.0, np.nan, 2.0, 3.0], "times_s contains NaN"),
        ([0.0, 1.0], r"times_s must have shape \(4,\)"),
    ]:
        with pytest.raises(ValueError, match=message):
            sim.drifting_navigation(truth, np.array(times))
    scaled = truth.copy()
    scaled[1, :3, :3] *= 5
    with pytest.raises(ValueError, match="truth is not rigid"):
        sim.drifting_navigation(scaled, np.arange(4.0))
    with pytest.raises(ValueError, match="seed"):
        sim.drifting_navigation(truth, np.arange(4.0), seed=-1)
    assert sim.drifting_navigation(truth[:0], np.zeros(0)).shape == (0, 4, 4)
    nav = sim.drifting_navigation(truth, np.array([0.0, 1.0, 1.0, 2.0]))  # a repeated time: no drift there
    assert np.all(np.isfinite(nav))


# ------------------------------------------------------------------ C. ground truth


@pytest.mark.parametrize("voxel_size", [0.0, -0.1, float("nan"), float("inf"), "0.1", None])
def test_occupancy_refuses_a_bad_voxel_size(voxel_size):
    with pytest.raises(ValueError, match="voxel_size must be a positive number"):
        scenes.load("boxes").occupancy(voxel_size)


@pytest.mark.parametrize("voxel_size", [1e-4, 1e-300, 0.01])
def test_occupancy_refuses_more_voxels_than_the_limit(voxel_size):
    with pytest.raises(ValueError, match=f"ground-truth voxels .* more than the limit of {MAX_GROUND_TRUTH_CELLS}"):
        scenes.load("boxes").occupancy(voxel_size)


def test_every_built_in_scene_fits_the_limit_down_to_5_cm_and_the_warehouse_to_10_cm():
    for name in scenes.NAMES:
        finest = 0.1 if name in scenes.GROUND_SCENES else 0.05  # 40 x 40 x 6 m at 5 cm is 77 M voxels
        region = scenes.load(name).region()
        cells = np.prod(np.floor(region[1] / finest) - np.floor(region[0] / finest) + 3)
        assert cells <= MAX_GROUND_TRUTH_CELLS, name


# ------------------------------------------------------------------ D. shared scenes


def test_loaded_scenes_cannot_be_changed_by_a_caller():
    scene = scenes.load("boxes")
    before = scene.bounds.copy()
    for array in (scene.bounds, scene.start_pose, scene.default_survey):
        with pytest.raises(ValueError, match="read-only"):
            array[0] += 100.0
    np.testing.assert_array_equal(scenes.load("boxes").bounds, before)
    survey = scene.survey(1)
    survey[0] += 1.0  # a fresh array, the caller's own
    assert not np.array_equal(survey, scene.default_survey)


def test_survey_and_surface_points_check_their_counts():
    scene = scenes.load("boxes")
    for laps in (0, -1, 1.5, 1001, True):
        with pytest.raises(ValueError, match="laps must be"):
            scene.survey(laps)
    for count in (0, -5, 2.0, 10**9):
        with pytest.raises(ValueError, match="count must be"):
            scene.surface_points(count)
    with pytest.raises(ValueError, match="name must be one of"):
        scenes.load(["boxes"])


# ------------------------------------------------------------------ E. metrics and map_run


def test_roc_refuses_nan_scores_and_non_boolean_truth():
    occupied = np.array([True, False, True, False])
    for scores in ([np.nan, 0.1, 0.8, 0.2], np.full(4, np.nan)):  # were AUC 0.5 and 0.75
        with pytest.raises(ValueError, match="scores contains NaN"):
            vj_eval.roc(np.array(scores), occupied)
    with pytest.raises(ValueError, match="occupied must hold booleans"):
        vj_eval.roc(np.array([0.9, 0.1, 0.8, 0.2]), np.array([0.5, 0, 0.5, 0]))
    scores = np.array([0.9, 0.1, 0.8, 0.2])
    assert vj_eval.roc(scores, np.array([1, 0, 1, 0])).auc == vj_eval.roc(scores, occupied).auc == 1.0
    assert vj_eval.roc(np.array([np.inf, -np.inf, 1.0, 0.0]), occupied).auc == 1.0


def test_misclassified_needs_two_1d_arrays_of_one_length():
    with pytest.raises(ValueError, match="states_a and states_b must be 1-D"):
        vj_eval.misclassified(np.ones((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="states_a and states_b must be 1-D"):
        vj_eval.misclassified(np.array([1, 2, 3]), np.array([1, 2]))


def test_map_run_checks_its_config_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="config must be a JobConfig, got dict"):
        vj_eval.map_run(tmp_path / "run.h5", tmp_path / "out", config={"x": 1})
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ F. geometry helpers


def test_pose_deltas_needs_rigid_poses():
    with pytest.raises(ValueError, match="T_new is not rigid"):  # was: (0, 0), no motion
        geometry.pose_deltas(np.eye(4), np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="T_old contains NaN"):
        geometry.pose_deltas(np.full((4, 4), np.nan), np.eye(4))
    with pytest.raises(ValueError, match=r"T_old must have shape \(\.\.\., 4, 4\)"):
        geometry.pose_deltas(np.eye(3), np.eye(4))
    # valid poses, batched and broadcast, as before (bit for bit)
    rng = np.random.default_rng(0)
    old = geometry.exp_se3(rng.normal(0, 0.3, (5, 6)))
    new = geometry.exp_se3(rng.normal(0, 0.3, (5, 6)))
    twist = geometry.log_se3(geometry.inverse(old) @ new)
    angle, shift = geometry.pose_deltas(old, new)
    np.testing.assert_array_equal(angle, np.linalg.norm(twist[:, :3], axis=-1))
    np.testing.assert_array_equal(shift, np.linalg.norm(twist[:, 3:], axis=-1))
    assert geometry.pose_deltas(np.eye(4), new)[0].shape == (5,)


def test_confidence_volume_needs_a_covariance():
    negative = np.eye(6)
    negative[3, 3] = -1.0
    with pytest.raises(ValueError, match="marginals must be positive semi-definite"):  # was: 0.0
        geometry.confidence_volume(negative)
    with pytest.raises(ValueError, match="marginals contains NaN"):  # was: NaN
        geometry.confidence_volume(np.full((6, 6), np.nan))
    with pytest.raises(ValueError, match="marginals must have shape"):
        geometry.confidence_volume(np.eye(3))
    # singular (PSD) and round-off below zero: a volume of 0, as GlobalMap accepts them
    singular = np.eye(6)
    singular[3, 3] = 0.0
    assert geometry.confidence_volume(singular) == 0.0
    singular[3, 3] = -1e-12
    assert geometry.confidence_volume(singular) == 0.0
    small = np.eye(6) * 1e-8  # tiny covariances keep their volume
    assert geometry.confidence_volume(small) == pytest.approx(
        4 / 3 * np.pi * geometry.CHI2_3DOF_95**1.5 * np.sqrt(1e-24), rel=1e-12
    )
    m = np.diag([1e-4, 1e-4, 4e-4, 1e-2, 9e-2, 1e-3])
    assert geometry.confidence_volume(m) == pytest.approx(
        4 / 3 * np.pi * geometry.CHI2_3DOF_95**1.5 * np.sqrt(1e-2 * 9e-2 * 4e-4), rel=1e-12
    )


def test_quaternion_conversions_check_their_input():
    with pytest.raises(ValueError, match="rotations must be proper rotations"):  # was: identity
        geometry.quaternions_from_rotations(2 * np.eye(3))
    with pytest.raises(ValueError, match="rotations must be proper rotations"):
        geometry.quaternions_from_rotations(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="quaternions contains NaN"):  # was: "zero norm quaternions"
        geometry.rotations_from_quaternions(np.full(4, np.nan))
    with pytest.raises(ValueError, match="quaternions must have non-zero norm"):
        geometry.rotations_from_quaternions(np.zeros((2, 4)))
    with pytest.raises(ValueError, match=r"quaternions must have shape \(\.\.\., 4\)"):
        geometry.rotations_from_quaternions(np.ones(3))
    R = geometry.rotation_from_ypr(np.array([0.3, -2.0]), 0.1, 0.2)
    np.testing.assert_allclose(
        geometry.rotations_from_quaternions(2 * geometry.quaternions_from_rotations(R)), R, atol=1e-12
    )


def test_map_refuses_a_ground_truth_beyond_the_limit_before_the_pipeline_runs(tmp_path):
    """`vogjax map` builds the scene's ground truth at the map's voxel size: too many voxels are
    refused before the pipeline runs, not after."""
    run = tmp_path / "run.h5"
    sim.simulate_run("boxes", run, num_scans=3, sensor=vj.SonarConfig(beams=4), progress=False)
    config = vj.config.JobConfig.from_dict({"pipeline": {"map": {"voxel_size": 0.015}}})
    for call in (
        lambda: vj_eval.map_runs([run], tmp_path / "out", config, progress=False),
        lambda: vj_eval.map_run(run, tmp_path / "out" / "run", config, progress=False),
    ):
        with pytest.raises(ValueError, match=f"more than the limit of {MAX_GROUND_TRUTH_CELLS}"):
            call()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.h5"]
