"""Simulation: sonar vs analytic intersections, drift statistics, the MJX vehicle, scenes, runs."""

import h5py
import numpy as np
import pytest
import trimesh
import warp as wp

import vogjax as vj
from vogjax import cli, scenes
from vogjax.geometry import pose_from_xyz_yaw as pose
from vogjax.geometry import yaw_pitch_roll
from vogjax.io.dataset import Dataset
from vogjax.scenes import analytic
from vogjax.sim import drifting_navigation, scan, simulate, simulate_batch, simulate_run


def warp_mesh(mesh):
    vj.devices.init()
    return wp.Mesh(
        points=wp.array(mesh.vertices, dtype=wp.vec3, device="cpu"),
        indices=wp.array(mesh.faces.reshape(-1), dtype=wp.int32, device="cpu"),
    )


def test_sonar_ranges_match_analytic_box_and_cylinder():
    rng = np.random.default_rng(0)
    config = vj.SonarConfig(min_range_m=0.0, max_range_m=20.0, fov_deg=60.0)
    box = trimesh.creation.box(extents=[2.0, 3.0, 1.5])
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, :3, 3] = rng.uniform(-8, 8, (40, 3)) * [1, 1, 0.2]
    outside = np.any(np.abs(poses[:, :3, 3]) > [1.2, 1.7, 0.9], axis=1)
    poses = poses[outside]
    for i, p in enumerate(poses):  # look at the box
        d = -p[:3, 3]
        poses[i, :3, :3] = pose(0, 0, 0, np.arctan2(d[1], d[0]))[:3, :3]
    scans = scan(warp_mesh(box), poses, config)
    starts = np.repeat(scans.origins, config.beams, axis=0)
    truth = analytic._box(
        starts, scans.directions.reshape(-1, 3), np.array([-1.0, -1.5, -0.75]), np.array([1.0, 1.5, 0.75])
    )
    hit = np.isfinite(truth)
    assert 0.2 < hit.mean() < 1.0
    np.testing.assert_array_equal(~scans.no_return.reshape(-1), hit)
    np.testing.assert_allclose(scans.ranges.reshape(-1)[hit], truth[hit], atol=1e-4)

    cylinder = trimesh.creation.cylinder(radius=1.0, height=4.0, sections=512)
    scans = scan(warp_mesh(cylinder), poses, config)
    truth = analytic._cylinder(starts, scans.directions.reshape(-1, 3), 0.0, 0.0, 1.0, -2.0, 2.0)
    hit = np.isfinite(truth) & ~scans.no_return.reshape(-1)
    assert hit.sum() > 100
    # the faceted cylinder lies within r (1 - cos(pi / 512)) = 2e-5 m of the true one; grazing
    # beams stretch that along the ray
    np.testing.assert_allclose(scans.ranges.reshape(-1)[hit], truth[hit], atol=5e-3)


def test_sonar_misses_and_aperture():
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    config = vj.SonarConfig(beams=5, fov_deg=4.0, tilt_deg=0.0, max_range_m=11.0)
    toward = pose(-5.0, 0, 0, 0)
    away = pose(-5.0, 0, 0, np.pi)
    scans = scan(warp_mesh(box), np.stack([toward, away]), config)
    np.testing.assert_allclose(scans.ranges[0], 4.5 / np.cos(np.deg2rad([-2, -1, 0, 1, 2])), atol=1e-4)
    assert scans.no_return[1].all() and np.isnan(scans.ranges[1]).all()
    # With an aperture, a beam aimed just beside the box still returns from its edge.
    beside = pose(-5.0, 0.6, 0, 0)
    narrow = scan(warp_mesh(box), beside[None], vj.SonarConfig(beams=1, fov_deg=1.0, tilt_deg=0.0))
    wide = scan(
        warp_mesh(box), beside[None], vj.SonarConfig(beams=1, fov_deg=1.0, tilt_deg=0.0, aperture_deg=4.0, subrays=9)
    )
    assert narrow.no_return.all() and not wide.no_return.any()


def test_navigation_drift_statistics_match_the_model():
    noise = vj.NavNoise()
    times = np.arange(301) * 0.2  # 60 s at 5 Hz
    truth = np.tile(pose(1.0, 2.0, 3.0, 0.3), (len(times), 1, 1))
    ends = np.stack([drifting_navigation(truth, times, noise, seed)[-1] for seed in range(300)])
    shift = ends[:, :3, 3] - truth[0, :3, 3]
    yaw = np.array([yaw_pitch_roll(e[:3, :3])[0] for e in ends]) - 0.3
    assert np.var(shift[:, 0]) == pytest.approx(noise.sigma2_x * 60, rel=0.25)
    assert np.var(shift[:, 1]) == pytest.approx(noise.sigma2_y * 60, rel=0.25)
    assert np.var(yaw) == pytest.approx(noise.sigma2_yaw * 60, rel=0.25)
    assert np.var(shift[:, 2]) == pytest.approx(noise.sigma2_z * 0.2, rel=0.25)  # absolute: no growth
    again = drifting_navigation(truth, times, noise, seed=5)
    np.testing.assert_array_equal(again, drifting_navigation(truth, times, noise, seed=5))


def test_controller_reaches_waypoints_within_the_limits():
    waypoints = np.array([[2.0, 0.0, 1.0, 0.0], [2.0, 2.0, 1.5, np.pi / 2], [0.0, 2.0, 1.5, np.pi]])
    poses, index = simulate(pose(0, 0, 1, 0), waypoints, 400)
    assert index[-1] == 2
    np.testing.assert_allclose(poses[-1, :3, 3], waypoints[-1, :3], atol=0.15)
    assert (
        abs(yaw_pitch_roll(poses[-1, :3, :3])[0] - np.pi) % (2 * np.pi) < 0.05
        or abs(abs(yaw_pitch_roll(poses[-1, :3, :3])[0]) - np.pi) < 0.05
    )
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * 5.0
    yaws = np.unwrap([yaw_pitch_roll(p[:3, :3])[0] for p in poses])
    assert speed.max() < 0.25 * 1.02 and np.abs(np.diff(yaws) * 5.0).max() < 0.15 * 1.02
    assert np.abs([yaw_pitch_roll(p[:3, :3])[1:] for p in poses]).max() < 1e-3  # stays level


def test_yaw_along_path_turns_while_translating_and_arrives_together():
    """With yaw_along_path the heading advances with the position along the straight line (the
    share of the turn done equals the share of the distance flown, up to the thrusters' lag),
    and both arrive at once; without it the translation ends early and the rest of the turn
    is flown in place."""
    from vogjax.config import ControllerConfig

    start, waypoint = pose(0.0, 0.0, 1.0, 0.0), np.array([[1.0, 0.5, 1.0, 2.0]])  # 1.1 m, 2 rad
    shares = {}
    for along in (True, False):
        poses, index = simulate(start, waypoint, 120, config=ControllerConfig(yaw_along_path=along))
        flown = np.linalg.norm(poses[:, :2, 3], axis=1) / np.linalg.norm(waypoint[0, :2])
        turned = np.unwrap([yaw_pitch_roll(p[:3, :3])[0] for p in poses]) / 2.0
        shares[along] = flown, turned
        np.testing.assert_allclose(poses[-1, :2, 3], waypoint[0, :2], atol=0.15)
        assert abs(turned[-1] - 1.0) < 0.05
    flown, turned = shares[True]
    moving = (flown > 0.05) & (flown < 0.9)
    assert np.abs(flown[moving] - turned[moving]).max() < 0.08
    # the translation alone takes 4.5 s at 0.25 m/s, the turn 13 s at 0.15 rad/s: without the
    # coupling the vehicle is there long before its heading
    flown, turned = shares[False]
    there = np.argmax(flown > 0.9)
    assert turned[there] < 0.5


def test_batched_vehicles_equal_one_at_a_time():
    starts = np.stack([pose(0, 0, 1, 0), pose(1, -1, 2, 1.0)])
    waypoints = np.stack([[[1.0, 1.0, 1.0, 0.5], [0.0, 1.0, 1.5, 1.0]], [[2.0, -1.0, 2.0, 0.0], [2.0, 0.0, 1.0, -1.0]]])
    batch, batch_index = simulate_batch(starts, waypoints, 60)
    for v in range(2):
        alone, index = simulate(starts[v], waypoints[v], 60)
        np.testing.assert_allclose(batch[v], alone, atol=1e-5)
        np.testing.assert_array_equal(batch_index[v], index)


@pytest.mark.parametrize("name, voxel_size", [("boxes", 0.1), ("tank", 0.1), ("propeller", 0.1), ("pilings", 0.2)])
def test_scenes_are_sane(name, voxel_size):
    scene = scenes.load(name)
    assert scene.mesh.is_watertight
    lo, hi = scene.bounds
    assert np.all(lo < hi) and np.all((scene.start_pose[:3, 3] >= lo) & (scene.start_pose[:3, 3] <= hi))
    truth = scene.occupancy(voxel_size)
    occupied = truth.centres(scenes.OCCUPIED)
    assert len(occupied) > 1000
    # occupied voxels lie on the mesh: the surface passes within half a voxel diagonal of the centre
    _, distance, _ = trimesh.proximity.closest_point(scene.mesh, occupied[:: max(1, len(occupied) // 2000)])
    assert distance.max() <= voxel_size * np.sqrt(3) / 2 + 1e-6
    # inside/outside against trimesh, part by part (parts touch, which ray parity dislikes)
    parts = scene.mesh.split(only_watertight=False)

    def contained(points):
        return np.any([part.contains(points) for part in parts], axis=0)

    inside = truth.centres(scenes.INSIDE)
    if len(inside):
        assert contained(inside[:: max(1, len(inside) // 500)]).mean() > 0.97
    free = truth.centres(scenes.FREE)
    assert not contained(free[np.random.default_rng(0).choice(len(free), 500)]).any()


def test_run_round_trip_cli_and_damaged_files(tmp_path, capsys):
    out = tmp_path / "run.h5"
    assert (
        cli.main(
            ["simulate", "--scene", "boxes", "--out", str(out), "--scans", "300", "--laps", "1", "--range-noise", "0"]
        )
        == 0
    )
    assert "300 scans" in capsys.readouterr().out
    with Dataset(out) as ds:
        assert len(ds) == 300 and ds.metadata["scene"] == "boxes"
        batches = list(ds.batches(128))
        assert [len(b) for b in batches] == [128, 128, 44]
        whole = ds.read(0, 300)
    np.testing.assert_array_equal(np.concatenate([b.ranges for b in batches]), whole.ranges)
    assert np.array_equal(np.isnan(whole.ranges), whole.no_return | whole.invalid) and 0.1 < whole.returned.mean()
    assert not np.any(whole.no_return & whole.invalid)
    # beams re-cast from the recorded truth poses land on the scene surface
    origins, ends = whole.world(whole.pose_truth, 11.0)
    hit = whole.returned
    mesh = scenes.load("boxes").mesh
    _, distance, _ = trimesh.proximity.closest_point(mesh, ends[hit][::50])
    assert distance.max() < 1e-3
    # the survey passes within the sonar's 0.5 m blind distance of a box (and its transit from
    # the start pokes the bow into one): those beams are invalid, not "no return". Against
    # trimesh (an independent reference): an invalid beam starts inside a solid or meets the
    # surface within 0.5 m; a beam without a return starts outside and meets nothing within 11 m.
    assert whole.invalid.sum() > 100
    starts = np.broadcast_to(origins[:, None], ends.shape)
    directions = np.einsum("sij,sbj->sbi", whole.pose_truth[:, :3, :3], whole.sonar_directions)
    parts = mesh.split(only_watertight=False)
    for flags, low, high in ((whole.invalid, 0.0, 0.5), (whole.no_return, np.inf, np.inf)):
        o, d = starts[flags][::7], directions[flags][::7]
        where, ray, _ = mesh.ray.intersects_location(o, d, multiple_hits=False)
        nearest = np.full(len(o), np.inf)
        np.minimum.at(nearest, ray, np.linalg.norm(where - o[ray], axis=1))
        nearest[nearest > 11.0] = np.inf
        inside = np.any([part.contains(o) for part in parts], axis=0)
        within = (nearest >= low - 1e-4) & (nearest <= high + 1e-4)
        expected = inside | within if flags is whole.invalid else ~inside & within
        assert np.all(expected), (low, high, inside.sum(), nearest[~expected][:5])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.h5"]  # no temporary left

    data = out.read_bytes()
    (tmp_path / "truncated.h5").write_bytes(data[: len(data) // 2])
    (tmp_path / "text.h5").write_text("not a run")
    newer = tmp_path / "newer.h5"
    newer.write_bytes(data)
    with h5py.File(newer, "a") as f:
        f.attrs["format_version"] = 99
    missing = tmp_path / "missing.h5"
    missing.write_bytes(data)
    with h5py.File(missing, "a") as f:
        del f["ranges"]
    for path, message in [
        (tmp_path / "truncated.h5", "truncated or corrupt"),
        (tmp_path / "text.h5", "truncated or corrupt"),
        (newer, "version 99"),
        (missing, "damaged"),
        (tmp_path / "nope.h5", "does not exist"),
    ]:
        with pytest.raises(ValueError, match=message):
            Dataset(path)


def test_bad_simulation_arguments(tmp_path):
    with pytest.raises(ValueError, match="name"):
        simulate_run("moon", tmp_path / "x.h5")
    with pytest.raises(ValueError, match="laps"):
        simulate_run("boxes", tmp_path / "x.h5", laps=0)
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--scene", "moon", "--out", str(tmp_path / "x.h5")])
    with pytest.raises(ValueError, match="beams"):
        vj.SonarConfig(beams=0)
    assert not list(tmp_path.iterdir())


def test_simulate_checks_its_output_before_any_work(tmp_path, capsys):
    existing = tmp_path / "run.h5"
    existing.write_bytes(b"an earlier run")
    with pytest.raises(ValueError, match="exists"):
        simulate_run("boxes", existing, num_scans=5, progress=False)
    assert existing.read_bytes() == b"an earlier run"
    with pytest.raises(ValueError, match="not a folder"):  # its folder is a file
        simulate_run("boxes", existing / "run.h5", num_scans=5, progress=False)
    (tmp_path / "folder.h5").mkdir()
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["simulate", "--scene", "boxes", "--scans", "5", "--out", str(tmp_path / "folder.h5")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "folder.h5" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.h5", "run.h5"]  # no debris
