"""The sonar's blind distance: a beam whose surface lies within it is invalid, recorded as such,
and clears no free space; so no map of a built-in scene holds free water behind a surface.

The reference is each scene's ground truth (`Scene.occupancy`: voxels wholly inside a solid
are INSIDE) and, for the tank, its analytic walls (the water outside them, below the rim,
cannot be seen from inside). Drift is made negligible and loop closures are off, so that every
map sits at the true poses: any free voxel there is a beam cleared through a surface, not a
misplaced map.
"""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
import warp as wp

import vogjax as vj
from vogjax import scenes
from vogjax.config import PipelineConfig
from vogjax.geometry import pose_from_xyz_yaw, yaw_pitch_roll
from vogjax.io.dataset import Dataset, DatasetWriter
from vogjax.pipeline import Mapper
from vogjax.sim import scan, simulate_run
from vogjax.sim.explore import explore, scene_planner

STILL = vj.NavNoise(*(1e-10,) * 6)  # navigation that does not drift: the maps sit at the true poses
SONAR = vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.0))
# scans of each scene's survey that include its passes within the blind distance (the pilings'
# first comes at scan 1024, the boxes' at 12; the propeller's and the tank's surveys have none)
DEMO_SCANS = {"propeller": 300, "pilings": 1100, "boxes": 400, "tank": 300}
TANK_OUTER_RADIUS_M, TANK_RIM_M = 3.7, 3.1
# the sonar's scenes: a ground scene (the warehouse) is a lidar's, its vehicle on the floor
SONAR_SCENES = [name for name in scenes.NAMES if name not in scenes.GROUND_SCENES]


def test_no_start_pose_is_within_the_blind_distance_of_a_surface():
    """Turning in place at the start (exploration's first motion), no beam of the papers'
    sonar meets a surface within its blind distance, nor within 0.25 m beyond it."""
    for name in SONAR_SCENES:
        scene = scenes.load(name)
        x, y, z = scene.start_pose[:3, 3]
        yaw = yaw_pitch_roll(scene.start_pose[:3, :3])[0]
        turn = np.array([pose_from_xyz_yaw(x, y, z, yaw + a) for a in np.linspace(0, 2 * np.pi, 361)])
        scans = scan(scene.warp_mesh, turn @ SONAR.T_vehicle_sensor, SONAR)
        assert not scans.invalid.any(), name
        assert np.nanmin(scans.ranges) > SONAR.min_range_m + 0.25, name


def test_invalid_beams_clear_nothing_and_differ_from_no_return():
    """A wall 0.3 m ahead of the sonar: the simulator marks the beams invalid; a map gets no
    voxel from them. The same beams taken as "no return" (the old reading) clear the wall."""
    import trimesh

    wall = trimesh.creation.box(extents=[0.2, 6.0, 6.0])
    wall.apply_translation([1.3, 0.0, 0.0])  # its face at x = 1.2: 0.3 m ahead of a bow sonar at 0.9
    mesh = scenes.scene._warp_mesh(wall)
    scans = scan(mesh, np.eye(4)[None] @ SONAR.T_vehicle_sensor, SONAR)
    assert scans.invalid.all() and not scans.no_return.any() and np.isnan(scans.ranges).all()
    fields = SONAR.dataset_fields(scans.ranges, scans.no_return, scans.invalid)
    origins, points, scan_index = vj.sensors.mapped_beams(
        *vj.sensors.world_rays(
            np.eye(4)[None],
            fields["sonar_origin"],
            fields["sonar_directions"],
            fields["ranges"],
            fields["no_return"],
            11.0,
            fields["invalid"],
        ),
        fields["invalid"],
    )
    assert len(points) == 0 and len(scan_index) == 0
    old = vj.VoxelMap(vj.MapConfig())
    old.integrate_scans(
        *vj.sensors.mapped_beams(
            *vj.sensors.world_rays(
                np.eye(4)[None],
                fields["sonar_origin"],
                fields["sonar_directions"],
                fields["ranges"],
                fields["invalid"],  # read as no return
                11.0,
            )
        )
    )
    inside_wall = np.array([[1.35, y, z] for y in (-0.05, 0.05) for z in np.arange(-0.55, 0.1, 0.1)])
    assert np.any(old.state(inside_wall) == vj.FREE)  # cleared through the wall


def test_run_files_record_invalid_beams_and_older_formats_load(tmp_path):
    """Format 3 stores `invalid`; a format-2 file (no such field) loads with no beam invalid; a
    format-3 file without it, or with a beam both invalid and without a return, is refused."""
    rng = np.random.default_rng(0)
    count, beams = 6, 5
    ranges = rng.uniform(1.0, 5.0, (count, beams))
    no_return = rng.random((count, beams)) < 0.3
    invalid = ~no_return & (rng.random((count, beams)) < 0.3)
    sonar = vj.sensors.ProfilingSonar(vj.SonarConfig(beams=beams))
    scans = {
        "time_s": np.arange(count) * 0.2,
        "pose_truth": np.tile(np.eye(4), (count, 1, 1)),
        "pose_nav": np.tile(np.eye(4), (count, 1, 1)),
        **sonar.dataset_fields(ranges, no_return, invalid),
    }
    path = tmp_path / "run.h5"
    with DatasetWriter(path, beams, {"scene": "test"}) as writer:
        writer.append(**scans)
    with Dataset(path) as run:
        batch = run.read(0, count)
        assert run.format_version == 3
    np.testing.assert_array_equal(batch.invalid, invalid)
    np.testing.assert_array_equal(batch.no_return, no_return)
    assert np.array_equal(batch.returned, ~no_return & ~invalid)
    older = tmp_path / "v2.h5"
    older.write_bytes(path.read_bytes())
    with h5py.File(older, "a") as f:
        del f["invalid"]
        f.attrs["format_version"] = 2
    with pytest.raises(ValueError, match="NaN exactly where"):  # its NaNs are now unexplained
        with Dataset(older) as run:
            run.read(0, count)
    with h5py.File(older, "a") as f:  # a format-2 file as format 2 wrote it: no invalid beam
        f["ranges"][...] = np.where(no_return, np.nan, ranges).astype(np.float32)
    with Dataset(older) as run:
        batch = run.read(0, count)
    assert not batch.invalid.any() and np.array_equal(batch.no_return, no_return)
    missing = tmp_path / "missing.h5"
    missing.write_bytes(path.read_bytes())
    with h5py.File(missing, "a") as f:
        del f["invalid"]
    with pytest.raises(ValueError, match="damaged"):
        Dataset(missing)
    both = dict(scans, no_return=no_return | invalid)
    with pytest.raises(ValueError, match="both no_return and invalid"):
        with DatasetWriter(tmp_path / "both.h5", beams, {"scene": "test"}) as writer:
            writer.append(**both)


@wp.kernel
def distance_to_surface(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), distance: wp.array(dtype=float)):
    tid = wp.tid()
    query = wp.mesh_query_point_no_sign(mesh, points[tid], 1.0e6)
    distance[tid] = 1.0e6
    if query.result:
        distance[tid] = wp.length(points[tid] - wp.mesh_eval_position(mesh, query.face, query.u, query.v))


def behind_surfaces(scene, truth, depth_m: float) -> np.ndarray:
    """(K,3) centres of the voxels labelled INSIDE (centre inside a solid) that lie deeper in
    it than depth_m (a voxel whose centre lies just inside can reach out of the solid, and a
    beam may then pass through its outer corner)."""
    centres = truth.centres(scenes.INSIDE)
    distance = wp.empty(len(centres), dtype=float, device="cpu")
    wp.launch(
        distance_to_surface,
        dim=len(centres),
        inputs=[scene.warp_mesh.id, wp.array(centres, dtype=wp.vec3, device="cpu")],
        outputs=[distance],
        device="cpu",
    )
    return centres[distance.numpy() > depth_m]


# Maps on the world's voxel grid: a FREE answer at a voxel centre means a beam crossed that
# voxel, which reaches half a diagonal from its centre. Maps of submaps read a point from the
# submap voxel holding it (pulled into the submap's own grid), which can reach a whole
# diagonal away. A point deeper than that inside a solid read as FREE: a beam crossed solid.
WORLD_GRID = {"standard", "confidence"}


def free_behind(scene, maps: dict, truth) -> dict:
    """Per map: its FREE voxels behind a surface (wholly inside a solid; for the tank also wholly
    outside its wall and below its rim, where no beam from inside can reach)."""
    diagonal = np.sqrt(3) * truth.voxel_size
    hidden = {reach: behind_surfaces(scene, truth, reach + 1e-3) for reach in (diagonal / 2, diagonal)}
    out = {}
    for name, m in maps.items():
        reach = diagonal / 2 if name in WORLD_GRID else diagonal
        count = int(np.count_nonzero(m.state(hidden[reach]) == vj.FREE)) if len(hidden[reach]) else 0
        if scene.name == "tank" and hasattr(m, "voxels"):
            centres = m.voxels()[0]
            free = centres[m.state(centres) == vj.FREE]
            radius = np.linalg.norm(free[:, :2], axis=1)
            outside = (radius > TANK_OUTER_RADIUS_M + reach) & (free[:, 2] < TANK_RIM_M - reach)
            count += int(np.count_nonzero(outside))
        out[name] = count
    return out


def all_maps(result) -> dict:
    maps = {
        "standard": result.standard_map,
        "global": result.global_map,
        "virtual": result.vog,
        "truth_virtual": result.truth_vog,
        "full_merge": result.full_merge,
        "truth_merge": result.truth_merge,
        "navigation_merge": result.navigation_merge,
    }
    if result.confidence_map is not None:
        maps["confidence"] = result.confidence_map
    return maps


@pytest.mark.parametrize("name", SONAR_SCENES)
def test_no_map_of_a_survey_or_an_exploration_holds_free_water_behind_a_surface(name, tmp_path):
    scene = scenes.load(name)
    truth = scene.occupancy(0.1)
    # no loop closures either: an ICP result a few cm off would move a submap, not clear a wall
    base = PipelineConfig()
    config = dataclasses.replace(
        base,
        nav_noise=STILL,
        scans_per_submap=60,
        confidence_map=True,
        loop_closure=base.loop_closure.replace(max_candidates=0),
    )
    # the demo's run: the scene's survey (as `vogjax demo` flies it), mapped by the pipeline
    run = tmp_path / "survey.h5"
    simulate_run(name, run, num_scans=DEMO_SCANS[name], sensor=SONAR, noise=STILL, progress=False)
    with Dataset(run) as ds:
        mapper = Mapper(config, ds.metadata)
        invalid = 0
        for batch in ds.batches(100):
            mapper.add(batch)
            invalid += int(batch.invalid.sum())
    assert (invalid > 0) == (name in ("pilings", "boxes"))  # the surveys that pass close to a surface
    survey = free_behind(scene, all_maps(mapper.result()), truth)
    # an exploration: the planner in the loop, from the start pose (a turn in place, then plans)
    kept = {}
    explore(
        name,
        tmp_path / "explore.h5",
        8,
        seed=1,
        planner_config=scene_planner(name, 1).replace(max_nodes=8, tolerance_nodes=24),
        pipeline_config=config,
        sensor=SONAR,
        noise=STILL,
        max_scans=500,
        progress=False,
        on_iteration=lambda mapper, plan, row: kept.update(mapper=mapper),
    )
    explored = free_behind(scene, all_maps(kept["mapper"].result()), truth) if kept else {}
    assert survey == dict.fromkeys(survey, 0) and explored == dict.fromkeys(explored, 0), (survey, explored)
