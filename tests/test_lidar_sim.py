"""The warehouse, the spinning lidar and the ground vehicle: geometry against the scene's mesh,
motion distortion against deskewing, the minimum range, the run file and the command line."""

import h5py
import numpy as np
import pytest
import trimesh

import vogjax as vj
from vogjax import cli, scenes, sensors
from vogjax.config import LidarConfig, NavNoise
from vogjax.geometry import yaw_pitch_roll
from vogjax.io.dataset import Dataset
from vogjax.sim.ground_vehicle import GroundVehicle
from vogjax.sim.lidar_mission import simulate_lidar_run

# a coarse lidar (180 columns) keeps the runs small; the geometry is the same
COARSE = LidarConfig(column_deg=2.0)
STILL = NavNoise(**dict.fromkeys(NavNoise().to_dict(), 1e-12))  # odometry without drift


def test_the_lidar_fires_16_rings_over_30_degrees_in_900_columns_over_the_sweep():
    lidar = sensors.SpinningLidar()
    assert lidar.beams == 900 * 16 and lidar.rate_hz == 10.0 and (lidar.min_range_m, lidar.max_range_m) == (0.5, 50.0)
    directions = lidar.beam_directions()[:, 0]
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    elevation = np.degrees(np.arcsin(directions[:, 2])).reshape(900, 16)
    np.testing.assert_allclose(elevation, np.tile(np.linspace(-15, 15, 16), (900, 1)), atol=1e-9)
    azimuth = np.degrees(np.arctan2(directions[:, 1], directions[:, 0])).reshape(900, 16) % 360
    np.testing.assert_allclose(azimuth[:, 0], np.arange(900) * 0.4, atol=1e-9)
    offsets = lidar.firing_offsets_s()
    assert offsets[0] == 0.0 and offsets.max() < 0.1 and np.all(np.diff(offsets) >= 0)
    np.testing.assert_array_equal(lidar.rings_of_beams()[:32], np.tile(np.arange(16), 2))
    again = sensors.from_metadata(lidar.metadata())  # what a run file records, read back
    assert isinstance(again, sensors.SpinningLidar) and again.config == lidar.config
    np.testing.assert_array_equal(again.T_vehicle_sensor, lidar.T_vehicle_sensor)
    with pytest.raises(ValueError, match="column_deg must divide 360"):
        LidarConfig(column_deg=0.7)
    with pytest.raises(ValueError, match="min_range_m"):
        LidarConfig(min_range_m=60.0)


def test_the_ground_vehicle_drives_its_route_at_its_speed_and_turn_rate():
    scene = scenes.load("warehouse")
    vehicle = GroundVehicle(scene.start_pose, scene.survey(2))
    t = np.linspace(0, vehicle.duration_s, 40001)
    poses = vehicle.poses(t)
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    # the route's length from the poses themselves: two laps of the 34 m square, its seven corners
    # (the last lap ends at the start) each a quarter circle of 4 m in place of 2 x 4 m of straight
    assert steps.sum() == pytest.approx(vehicle.length_m, rel=1e-6)
    assert vehicle.length_m == pytest.approx(8 * 34 - 7 * (2 * 4.0 - np.pi / 2 * 4.0), rel=1e-9)
    assert (steps / np.diff(t)).max() <= 2.0 + 1e-9
    yaw = np.unwrap(yaw_pitch_roll(poses[:, :3, :3])[:, 0])
    assert np.abs(np.diff(yaw) / np.diff(t)).max() <= 2.0 / 4.0 + 1e-6
    assert yaw[-1] - yaw[0] == pytest.approx(7 * np.pi / 2, abs=1e-6)  # seven left turns
    np.testing.assert_allclose(poses[-1, :3, 3], scene.start_pose[:3, 3], atol=1e-9)
    # the vehicle heads along its path, and stays 3 m clear of the walls, on the floor
    heading = np.arctan2(np.diff(poses[:, 1, 3]), np.diff(poses[:, 0, 3]))
    moving = steps > 1e-6
    assert np.abs(np.angle(np.exp(1j * (heading - yaw[1:]))))[moving].max() < 1e-3
    assert np.abs(poses[:, :2, 3]).max() <= 17.0 + 1e-9 and np.all(poses[:, 2, 3] == 0.0)
    with pytest.raises(ValueError, match="too short"):
        GroundVehicle(scene.start_pose, [[-16.0, -17.0, 0, 0], [-16.0, -10.0, 0, 0]])


def test_every_return_lies_on_the_scene_and_every_miss_misses(tmp_path):
    """Fired at the stamp, with exact ranges: each end point, placed by the true pose, on the mesh."""
    summary = simulate_lidar_run(
        "warehouse",
        tmp_path / "w.h5",
        num_scans=3,
        sensor=sensors.SpinningLidar(COARSE),
        sweep="instant",
        progress=False,
    )
    assert summary.scans == 3 and summary.invalid == 0.0 and summary.returns > 0.99
    scene = scenes.load("warehouse")
    with Dataset(summary.path) as run:
        batch = run.read(0, 3)
        assert run.optional == ("ring",) and run.metadata["sweep"]["mode"] == "instant"
        assert run.metadata["sensor"] == "spinning_lidar" and run.metadata["odometry"]["kind"] == "wheel"
    origins, ends = batch.world(batch.pose_truth, 50.0)
    hit = ~batch.no_return
    points = ends[hit][::7]
    _, distance, _ = trimesh.proximity.closest_point(scene.mesh, points)
    assert distance.max() < 1e-3
    # misses: the mesh's own ray cast finds nothing within 50 m
    starts = np.repeat(origins, batch.no_return.shape[1], axis=0)[~hit.reshape(-1)]
    directions = np.einsum("sij,sbj->sbi", batch.pose_truth[:, :3, :3], batch.sonar_directions).reshape(-1, 3)
    directions = directions[~hit.reshape(-1)]
    if len(starts):
        found, rays, _ = scene.mesh.ray.intersects_location(starts, directions, multiple_hits=False)
        near = np.linalg.norm(found - starts[rays], axis=1) <= 50.0 - 1e-3
        assert not near.any()


def test_deskewing_undoes_the_motion_distortion_of_the_sweep(tmp_path):
    """Both runs cast the same rays; where each beam truly hit is the sensor's closed-form pose at
    its firing time applied to the raw point. At 2 m/s a raw sweep's late columns sit 0.15-0.2 m
    off it; deskewed with the (here drift-free) odometry, every point lands on it."""
    scene = scenes.load("warehouse")
    lidar = sensors.SpinningLidar(COARSE)
    ends = {}
    for sweep in ("raw", "deskewed"):
        path = tmp_path / f"{sweep}.h5"
        simulate_lidar_run("warehouse", path, num_scans=60, sensor=lidar, noise=STILL, sweep=sweep, progress=False)
        with Dataset(path) as run:
            batches = run.read(50, 60)  # cruising at 2 m/s
        ends[sweep] = batches.world(batches.pose_truth, 50.0)[1]
        if sweep == "raw":
            raw = batches
    vehicle = GroundVehicle(scene.start_pose, scene.survey(2))
    fired = raw.time_s[:, None] + lidar.firing_offsets_s()[None, :]
    T = vehicle.poses(fired.reshape(-1)) @ lidar.T_vehicle_sensor
    # each raw point in the sensor's frame: the beam's vehicle-frame direction turned back by the mount
    local = (raw.sonar_directions * raw.ranges[..., None]).reshape(-1, 3) @ lidar.T_vehicle_sensor[:3, :3]
    truth = (np.einsum("nij,nj->ni", T[:, :3, :3], local) + T[:, :3, 3]).reshape(ends["raw"].shape)
    hit = ~raw.no_return
    late = hit & (lidar.firing_offsets_s() >= 0.075)[None, :]
    raw_error = np.linalg.norm(ends["raw"] - truth, axis=-1)[late]
    # the distance driven since the stamp, give or take the floor's pitch and roll in between
    np.testing.assert_allclose(raw_error, 2.0 * (fired - raw.time_s[:, None])[late], rtol=0.02, atol=0.02)
    assert np.linalg.norm(ends["deskewed"] - truth, axis=-1)[hit].max() < 1e-3
    # and the deskewed points lie on the mesh
    points = ends["deskewed"][hit][::11]
    assert trimesh.proximity.closest_point(scene.mesh, points)[1].max() < 2e-3


def test_beams_nearer_than_the_minimum_range_are_invalid_and_padded_with_returns(tmp_path):
    """At the start the south wall is 3 m away: with a 4 m minimum range its near beams are invalid.
    (Raw: the ranges as measured; deskewing moves a point by the sensor's motion since the stamp.)"""
    lidar = sensors.SpinningLidar(LidarConfig(column_deg=2.0, min_range_m=4.0))
    summary = simulate_lidar_run(
        "warehouse", tmp_path / "near.h5", num_scans=2, sensor=lidar, sweep="raw", progress=False
    )
    assert summary.invalid > 0.01
    with Dataset(summary.path) as run:
        batch = run.read(0, 2)
        assert run.metadata["sweep"]["invalid_beams"] == round(summary.invalid * 2 * lidar.beams)
    returned = batch.ranges[~batch.no_return]
    assert returned.min() >= 4.0
    for scan in range(2):  # the padding: copies of a return of the same scan
        rows = np.c_[batch.sonar_directions[scan], batch.ranges[scan]]
        unique, counts = np.unique(rows, axis=0, return_counts=True)
        assert counts.max() - 1 >= summary.invalid * lidar.beams * 0.5
        assert np.isfinite(unique[counts.argmax(), 3])


def test_runs_are_deterministic_and_the_cli_picks_the_scenes_sensor(tmp_path, capsys):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    assert cli.main(["simulate", "--scene", "warehouse", "--scans", "4", "--seed", "3", "--out", str(a), "-q"]) == 0
    assert "lidar scans (deskewed)" in capsys.readouterr().out
    lidar = sensors.SpinningLidar(LidarConfig(range_noise_m=0.02))  # the command's default noise
    simulate_lidar_run("warehouse", b, num_scans=4, seed=3, sensor=lidar, progress=False)
    with h5py.File(a) as fa, h5py.File(b) as fb:
        for name in ("ranges", "sonar_directions", "pose_nav", "pose_truth", "ring"):
            np.testing.assert_array_equal(fa[name][()], fb[name][()])
    for argv, message in (
        (["--scene", "warehouse", "--sensor", "sonar"], "ground scene, driven with --sensor lidar"),
        (["--scene", "boxes", "--sensor", "lidar"], "underwater scene, flown with --sensor sonar"),
        (["--scene", "boxes", "--sweep", "raw"], "--sweep applies to --sensor lidar only"),
    ):
        with pytest.raises(SystemExit) as exit_:
            cli.main(["simulate", *argv, "--out", str(tmp_path / "x.h5")])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    with pytest.raises(ValueError, match="no ground scene"):
        simulate_lidar_run("boxes", tmp_path / "y.h5", num_scans=1)
    assert vj.sim.simulate_lidar_run is simulate_lidar_run


def test_the_wheel_odometry_drifts_in_yaw_at_its_preset_rate_and_keeps_z_pitch_roll():
    from vogjax.config.presets import WHEEL_ODOMETRY
    from vogjax.sim.ground_vehicle import ODOMETRY_RATE_HZ
    from vogjax.sim.navigation import drifting_navigation

    scene = scenes.load("warehouse")
    vehicle = GroundVehicle(scene.start_pose, scene.survey(1))
    t = np.arange(int(10 * ODOMETRY_RATE_HZ) + 1) / ODOMETRY_RATE_HZ
    truth = vehicle.poses(t)
    steps, z_errors, tilt_errors = [], [], []
    for seed in range(5):
        nav = drifting_navigation(truth, t, WHEEL_ODOMETRY, seed)
        errors = np.linalg.inv(truth) @ nav
        yaw = np.unwrap(np.arctan2(errors[:, 1, 0], errors[:, 0, 0]))
        steps.append(np.diff(yaw))
        z_errors.append(nav[:, 2, 3] - truth[:, 2, 3])
        tilt_errors.append(np.arccos(np.clip(np.einsum("si,si->s", nav[:, :3, 2], truth[:, :3, 2]), -1, 1)))
    # the reference: a random walk's steps have variance sigma^2 dt (5,000 of them: within 10%)
    assert np.var(np.concatenate(steps)) == pytest.approx(WHEEL_ODOMETRY.sigma2_yaw / ODOMETRY_RATE_HZ, rel=0.1)
    # z, pitch and roll are measured absolutely: one step's noise, not 10 s of walk
    assert np.var(np.concatenate(z_errors)) < 0.05 * WHEEL_ODOMETRY.sigma2_z * t[-1]
    assert np.mean(np.square(np.concatenate(tilt_errors))) < 0.05 * 2 * WHEEL_ODOMETRY.sigma2_pitch * t[-1]
