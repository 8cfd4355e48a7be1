"""Scan matching over the recorded odometry: against the simulator's true poses, against itself
batched differently, with drift-free odometry, in the mapper and in the presets."""

import dataclasses

import numpy as np
import pytest

from vogjax import sensors
from vogjax.config import JobConfig, LidarConfig, NavNoise, PipelineConfig, ScanMatchingConfig, presets
from vogjax.config.presets import WHEEL_ODOMETRY
from vogjax.io.dataset import Dataset, ScanBatch
from vogjax.pipeline.mapper import Mapper, vehicle_returns
from vogjax.sim.lidar_mission import simulate_lidar_run
from vogjax.slam import ScanMatcher

COARSE = LidarConfig(column_deg=1.0)  # 5,760 beams a scan: small runs, the same walls
STILL = NavNoise(**dict.fromkeys(NavNoise().to_dict(), 1e-12))  # odometry without drift
# thirty times wheel odometry's yaw drift: 5 degrees within the 15 s run
DRIFTING = WHEEL_ODOMETRY.replace(sigma2_yaw=3e-4)
CONFIG = ScanMatchingConfig(enabled=True)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two 150-scan warehouse runs (15 s: starting off, then 2 m/s down the aisle), one with
    drifting odometry and one with exact odometry, as scan batches; and their metadata."""
    out = {}
    for name, noise in (("drifting", DRIFTING), ("still", STILL)):
        path = tmp_path_factory.mktemp("scan_matching") / f"{name}.h5"
        lidar = sensors.SpinningLidar(COARSE)
        simulate_lidar_run("warehouse", path, num_scans=150, seed=1, sensor=lidar, noise=noise, progress=False)
        with Dataset(path) as run:
            out[name] = run.read(0, len(run))
            out["metadata"] = run.metadata
    return out


def _errors(poses: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rms position error in m, largest heading error in degrees) against the truth."""
    rms = float(np.sqrt(np.mean(np.sum((poses[:, :3, 3] - truth[:, :3, 3]) ** 2, axis=1))))
    heading = np.arctan2(poses[:, 1, 0], poses[:, 0, 0]) - np.arctan2(truth[:, 1, 0], truth[:, 0, 0])
    return rms, float(np.degrees(np.abs(np.angle(np.exp(1j * heading)))).max())


def _correct(matcher: ScanMatcher, batch: ScanBatch, reach_m: float = 50.0) -> np.ndarray:
    return matcher.correct(batch.time_s, batch.pose_nav, lambda j: vehicle_returns(batch, j, reach_m))


def _matched(batch: ScanBatch, size: int, config: ScanMatchingConfig = CONFIG) -> tuple[np.ndarray, ScanMatcher]:
    matcher = ScanMatcher(config)
    parts = [_correct(matcher, batch.rows(lo, min(lo + size, len(batch)))) for lo in range(0, len(batch), size)]
    return np.concatenate(parts), matcher


def test_scan_matching_recovers_the_position_and_heading_the_odometry_lost(runs):
    batch = runs["drifting"]
    poses, matcher = _matched(batch, 50)
    odometry_rms, odometry_heading = _errors(batch.pose_nav, batch.pose_truth)
    rms, heading = _errors(poses, batch.pose_truth)
    assert odometry_rms > 0.5 and odometry_heading > 3.0  # the drift the matcher has to undo
    assert rms < 0.1 * odometry_rms
    assert heading < 0.3 * odometry_heading  # between registrations the odometry's turn drifts on
    assert matcher.registered == 29 and matcher.failed == 0  # every 0.5 s after the first scan
    np.testing.assert_array_equal(poses[0], batch.pose_nav[0])  # the first scan anchors the run
    # rigid poses: each a rotation and a translation
    rotations = poses[:, :3, :3]
    np.testing.assert_allclose(
        rotations @ rotations.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-9
    )
    np.testing.assert_array_equal(poses[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(poses), 4)))


def test_the_same_scans_give_the_same_poses_however_they_are_batched(runs):
    batch = runs["drifting"]
    one, _ = _matched(batch, len(batch))
    for size in (1, 7, 64):
        np.testing.assert_array_equal(_matched(batch, size)[0], one)


def test_exact_odometry_stays_exact_within_the_registration_noise(runs):
    batch = runs["still"]
    rms, heading = _errors(_matched(batch, 50)[0], batch.pose_truth)
    assert rms < 0.03 and heading < 0.15


def test_the_mapper_maps_with_the_matched_poses_and_keeps_the_recorded_odometry(runs):
    batch = runs["drifting"].rows(0, 60)
    config = PipelineConfig(
        scan_matching=CONFIG,
        scans_per_submap=30,
        standard_map=False,
        timing=PipelineConfig().timing.replace(every_submaps=0),
    )
    config = config.replace(map=config.map.replace(voxel_size=0.4, max_range=50.0))
    mapper = Mapper(config, runs["metadata"])
    for lo in range(0, 60, 25):
        mapper.add(batch.rows(lo, min(lo + 25, 60)))
    result = mapper.result()
    np.testing.assert_array_equal(result.scan_navigation, _matched(batch, 60)[0])
    np.testing.assert_array_equal(result.scan_odometry, batch.pose_nav)
    bases = result.submap_base_scan
    np.testing.assert_array_equal(result.navigation, result.scan_navigation[bases])
    errors = result.metrics["trajectory_rmse_m"]
    assert errors["navigation"] < 0.5 * errors["odometry"]
    assert len(result.timings["scan_matching"]) == 3
    assert result.scan_matching == {"enabled": True, "registered": 11, "failed": 0}  # 6 s: every 0.5 s
    # off, the recorded odometry is the navigation and no odometry is kept apart
    off = Mapper(dataclasses.replace(config, scan_matching=ScanMatchingConfig()), runs["metadata"])
    off.add(batch)
    plain = off.result()
    assert plain.scan_odometry is None and "odometry" not in plain.metrics["trajectory_rmse_m"]
    assert plain.scan_matching == {"enabled": False, "registered": 0, "failed": 0}
    np.testing.assert_array_equal(plain.scan_navigation, batch.pose_nav)


def test_the_lidar_preset_turns_scan_matching_on_and_no_other_does():
    lidar = {"sensor": "spinning_lidar", "sensor_config": {"rings": 16, "max_range_m": 50.0, "rate_hz": 10.0}}
    lidar["odometry"] = {"kind": "wheel"}
    derived = presets.derive(lidar, JobConfig(), given=set())
    assert derived.config.pipeline.scan_matching.enabled
    assert derived.config.pipeline.scan_matching.icp.free == derived.config.pipeline.loop_closure.icp.free == "yaw"
    assert any("scan_matching.enabled = true" in line for line in derived.lines())
    for sensor in ("sonar", "depth_camera", "laser_scan"):
        assert not presets.derive(lidar, JobConfig(), given=set(), sensor=sensor).config.pipeline.scan_matching.enabled
    # what the user set wins
    given = JobConfig.from_document({"scan_matching": {"enabled": False}})
    assert not presets.derive(lidar, given, given={"scan_matching.enabled"}).config.pipeline.scan_matching.enabled


@pytest.mark.parametrize(
    ("changes", "name"),
    [({"every_s": 0.0}, "every_s"), ({"window_s": -1.0}, "window_s"), ({"voxel_m": float("nan")}, "voxel_m")],
)
def test_bad_settings_are_refused_by_name(changes, name):
    with pytest.raises(ValueError, match=name):
        ScanMatchingConfig(**changes)


def test_bad_arguments_are_refused_by_name_before_anything_changes(runs):
    with pytest.raises(ValueError, match="config"):
        ScanMatcher("lidar")
    batch = runs["still"].rows(0, 3)
    matcher = ScanMatcher(CONFIG)
    returns = lambda j: vehicle_returns(batch, j, 50.0)  # noqa: E731
    bad = [
        ("time_s", (batch.time_s[:, None], batch.pose_nav, returns)),
        ("time_s", (np.array([0.0, np.nan, 0.2]), batch.pose_nav, returns)),
        ("time_s", (batch.time_s[::-1].copy(), batch.pose_nav, returns)),
        ("T_world_vehicle", (batch.time_s, batch.pose_nav[:2], returns)),
        (
            "T_world_vehicle is not rigid",
            (batch.time_s, batch.pose_nav * np.r_[[1.1, 1.1, 1.1, 1.0]][:, None], returns),
        ),
        ("returns_of", (batch.time_s, batch.pose_nav, None)),
        ("returns_of", (batch.time_s, batch.pose_nav, lambda j: np.full((4, 3), np.nan))),
    ]
    for name, arguments in bad:
        with pytest.raises(ValueError, match=name):
            matcher.correct(*arguments)
    assert (matcher.registered, matcher.failed) == (0, 0)
    np.testing.assert_array_equal(_correct(matcher, batch), batch.pose_nav)  # the anchor and its slot
    with pytest.raises(ValueError, match="increase"):  # scans already corrected
        _correct(matcher, batch)


def test_returns_past_the_reach_are_left_out_as_the_maps_leave_them(runs):
    batch = runs["still"].rows(0, 1)
    near = vehicle_returns(batch, 0, 10.0)
    ranges = batch.ranges[0][batch.returned[0]]
    assert 0 < len(near) == np.count_nonzero(ranges <= 10.0) < len(ranges)
    origin = batch.sonar_origin[0]
    assert np.linalg.norm(near - origin, axis=1).max() <= 10.0 + 1e-5


def test_scans_without_returns_keep_the_odometry_and_are_counted(runs):
    batch = runs["drifting"].rows(0, 30)
    matcher = ScanMatcher(CONFIG)
    poses = matcher.correct(batch.time_s, batch.pose_nav, lambda j: np.zeros((0, 3)))
    np.testing.assert_array_equal(poses, batch.pose_nav)
    assert (matcher.registered, matcher.failed) == (0, 6)  # every 0.5 s of 3 s: nothing to register


def test_registrations_that_do_not_converge_keep_the_odometrys_motion(runs):
    batch = runs["drifting"].rows(0, 30)
    never = CONFIG.replace(icp=CONFIG.icp.replace(max_iterations=1, tolerance=1e-12))
    poses, matcher = _matched(batch, 30, never)
    np.testing.assert_allclose(poses, batch.pose_nav, atol=1e-12)  # the anchor's correction, the identity
    assert (matcher.registered, matcher.failed) == (0, 5)


def test_jittered_scan_times_keep_one_registration_per_slot(runs):
    """A driver's stamps jitter by a fraction of a millisecond: registrations stay on the
    every_s grid (one per slot), not drifting to every sixth scan."""
    batch = runs["still"]
    jitter = np.random.default_rng(0).uniform(-2e-4, 2e-4, len(batch))
    jitter[0] = 0.0
    jittered = dataclasses.replace(batch, time_s=batch.time_s + jitter)
    _, matcher = _matched(jittered, 50)
    slots = np.floor((jittered.time_s - jittered.time_s[0]) / CONFIG.every_s + 1e-6)
    assert matcher.registered + matcher.failed == len(np.unique(slots)) - 1 == 29
