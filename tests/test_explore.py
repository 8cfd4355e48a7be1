"""Closed-loop exploration: stepwise navigation and flight, and a short run of `vogjax explore`
checked against the true scene and against reprocessing its own run file."""

import csv

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli, scenes
from vogjax.geometry import pose_from_xyz_yaw
from vogjax.io.dataset import Dataset
from vogjax.sim import drifting_navigation, simulate
from vogjax.sim.explore import CSV_FIELDS
from vogjax.sim.stepped_navigation import SteppedNavigation
from vogjax.sim.vehicle import fly, resting_state

BOX_M = np.array([1.0, 1.0, 0.5])


def test_stepped_navigation_equals_one_call_over_the_run():
    rng = np.random.default_rng(0)
    truth = np.array([pose_from_xyz_yaw(*rng.uniform(-5, 5, 3), rng.uniform(-3, 3)) for _ in range(57)])
    times = np.cumsum(rng.uniform(0.1, 0.3, 57))
    stepped = SteppedNavigation(vj.NavNoise(), seed=3)
    pieces = [stepped.extend(truth[a:b], times[a:b]) for a, b in ((0, 1), (1, 20), (20, 21), (21, 57))]
    np.testing.assert_array_equal(np.concatenate(pieces), drifting_navigation(truth, times, vj.NavNoise(), seed=3))


def test_flight_continued_in_pieces_follows_one_flight():
    start = pose_from_xyz_yaw(0.0, 0.0, 1.0, 0.3)
    waypoints = np.array([[2.0, 1.0, 1.5, 1.0]])
    whole, _ = simulate(start, waypoints, 30)
    qpos, qvel = resting_state(start)
    poses = []
    for _ in range(3):
        flight = fly(qpos, qvel, waypoints, 10)
        poses.append(flight.poses)
        qpos, qvel = flight.qpos[-1], flight.qvel[-1]
    np.testing.assert_allclose(np.concatenate(poses), whole, atol=1e-4)
    assert np.linalg.norm(whole[-1, :3, 3] - start[:3, 3]) > 1.0  # it flew


def box_hits(scene, poses) -> int:
    """Scans at which the collision box around the true pose holds a point of the true surface,
    or whose centre lies inside a solid."""
    surface = scene.surface_points(150_000)
    hits = 0
    for pose in poses:
        inside = np.all(np.abs(surface - pose[:3, 3]) <= BOX_M / 2, axis=1)
        hits += bool(inside.any())
    truth = scene.occupancy(0.1)
    keys = np.floor(poses[:, :3, 3] / 0.1).astype(int) - truth.first_key
    labels = truth.labels[tuple(keys.T)]
    return hits + int(np.sum(labels == scenes.INSIDE))


def test_explore_boxes_never_hits_the_scene_and_reprocesses_to_the_same_map(tmp_path, capsys):
    settings = tmp_path / "explore.toml"
    settings.write_text("[pipeline]\nscans_per_submap = 60\n[planner]\nmax_nodes = 10\ntolerance_nodes = 30\n")
    out = tmp_path / "boxes.h5"
    assert (
        cli.main(
            [
                "explore",
                "--scene",
                "boxes",
                "--submaps",
                "6",
                "--out",
                str(out),
                "--seed",
                "1",
                "--config",
                str(settings),
                "--quiet",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "stopped: submaps" in printed
    with open(tmp_path / "boxes.explore.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == list(CSV_FIELDS) and len(rows) >= 3
    assert all(float(r["plan_s"]) > 0 and int(r["rays"]) > 0 for r in rows)
    # predicted and realised gain per iteration: what the flown edge's views would see, and the
    # volume the flight added to the gain region
    assert all(float(r["predicted_m3"]) >= 0 and np.isfinite(float(r["realised_m3"])) for r in rows)
    assert sum(float(r["realised_m3"]) for r in rows) > 0 and {r["step"] for r in rows} <= {"local", "global"}
    scene = scenes.load("boxes")
    with Dataset(out) as run:
        assert run.metadata["mission"] == "explore" and run.metadata["planner"]["max_nodes"] == 10
        truth = run.read(0, len(run)).pose_truth
        assert len(run) >= 6 * 60
    assert box_hits(scene, truth) == 0
    # waypoints keep the box inside the exploration bounds
    goals = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows])
    lo, hi = scene.bounds[0] + BOX_M / 2 - 1e-6, scene.bounds[1] - BOX_M / 2 + 1e-6
    assert np.all((goals >= lo) & (goals <= hi))
    path = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()
    assert path == pytest.approx(float(printed.split(" m flown")[0].split()[-1]), abs=0.06)
    # the run is a normal run: reprocessing it builds the online map again, bit for bit
    result = vj.pipeline.run(out, vj.PipelineConfig(scans_per_submap=60), progress=False)
    centres, values = result.global_map.voxels()
    lo, hi = scene.region()
    inside = np.all((centres >= lo) & (centres <= hi), axis=1)
    cfg = result.config.map
    known = (values <= cfg.log_free) | (values >= cfg.log_occupied)
    explored = np.count_nonzero(inside & known) * cfg.voxel_size**3
    assert f"{explored:.1f} m^3 explored" in printed


class _Discard:
    def append(self, **fields):
        pass


def test_the_planner_sees_the_scans_the_mapper_still_holds():
    """The mapper holds a submap's scans until it is complete; the planning map lays them over
    the global map at the poses the planner estimates, so a plan sees every scan so far: before
    the first submap, gains on it equal those on the standard map (the same scans, the same
    frame), and after one, the held scans are exactly those the mapper has not put in a submap."""
    from vogjax.config import PipelineConfig
    from vogjax.sim.explore import _Loop

    scene = scenes.load("boxes")
    sonar = vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.0))
    loop = _Loop(scene, sonar, vj.NavNoise(), 0, PipelineConfig(scans_per_submap=40), sonar.metadata())
    loop.writer = _Discard()
    x, y, z, yaw = loop.true_state()
    loop.fly([[x, y, z, yaw + 0.9]], timeout_s=5.0)  # 30 scans (pieces of 10): no submap finished
    assert loop.scans == 30 and loop.mapper.num_submaps == 0
    views = np.array([pose_from_xyz_yaw(x, y, z, yaw + a) for a in np.linspace(0, 1, 6)]) @ sonar.T_vehicle_sensor
    planned = vj.planner.view_gain(loop.planning_map("global"), views, sonar, max_range_m=5.0)
    standard = vj.planner.view_gain(loop.mapper.standard_map, views, sonar, max_range_m=5.0)
    np.testing.assert_array_equal(planned.unknown, standard.unknown)
    np.testing.assert_array_equal(planned.occupied, standard.occupied)
    assert planned.occupied.sum() > 0
    without = vj.planner.view_gain(loop.mapper.global_map, views, sonar, max_range_m=5.0)
    assert without.occupied.sum() == 0  # what the planner saw before: nothing
    loop.fly([[x, y, z, yaw + 2.0]], timeout_s=10.0)  # on, past the first submap's 40 scans
    assert loop.mapper.num_submaps == 1
    held = loop.held_scans_map()
    first = loop.mapper.submaps[0].scans
    reference = vj.VoxelMap(loop.mapper.config.map)
    correction = loop.correction("global")
    for batch in loop._batches:
        part = batch.rows(max(first - batch.first, 0), len(batch))
        if len(part):
            reference.integrate_scans(*part.beams(correction @ part.pose_nav, loop.mapper.reach_m))
    centres, _ = reference.voxels()
    np.testing.assert_array_equal(held.state(centres), reference.state(centres))
    assert len(held.submap(0).voxels()[0]) == len(centres)


def test_explore_rejects_bad_input(tmp_path, capsys):
    for argv, word in ((["--submaps", "0"], "submaps"), (["--submaps", "2", "--seed", "-1"], "seed")):
        with pytest.raises(SystemExit) as stop:
            cli.main(["explore", "--scene", "boxes", "--out", str(tmp_path / "x.h5"), *argv])
        assert stop.value.code == 2 and word in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["explore", "--scene", "nowhere", "--submaps", "2", "--out", str(tmp_path / "x.h5")])
    assert "argument --scene: invalid choice 'nowhere'" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()
