"""What a review of the Python API found (2026-12-04): the virtual map keyed points apart from
every other map, one large marginal hid a broken one, a repeated id in set_poses, a path that is
no path, and messages that named the wrong argument or none."""

from __future__ import annotations

import numpy as np
import pytest

import vogjax as vj
from vogjax import geometry
from vogjax.io import octomap
from vogjax.maps.blockmap import FREE, OCCUPIED

CFG = vj.MapConfig(voxel_size=0.2, max_range=4.0)


def one_submap(pose=None) -> vj.VogMap:
    vog = vj.VogMap(CFG, device="cpu")
    i = vog.add_submap(np.eye(4) if pose is None else pose)
    vog.submap(i).integrate_scan([1.9, 0.1, 0.1], [[0.7, 0.1, 0.1]])  # voxel x=3 occupied, 4..9 free
    return vog


@pytest.mark.parametrize("offset", [-1e-10, -1e-9, 0.0, 1e-9, -3e-8, 3e-8])
def test_every_map_keys_a_point_as_the_others_do(offset):
    """At 1e-10 below a voxel face the virtual map (in float64) found the voxel below, every
    other map (points rounded to float32, as documented) the voxel above: one point OCCUPIED at
    level 0 and FREE at level 1 of the same VogMap."""
    vog = one_submap()
    merged = vj.GlobalMap(CFG, device="cpu")
    merged.merge(vog)
    points = np.array([[0.8 + offset, 0.1, 0.1], [0.6 + offset, 0.1, 0.1]])
    level_0 = vog.state(points)
    np.testing.assert_array_equal(level_0, merged.state(points))
    np.testing.assert_array_equal(level_0, vog.submap(0).state(points))
    np.testing.assert_array_equal(vog.log_odds(points), merged.log_odds(points))
    coarse = vog.state(points, level=1)
    assert not np.any((level_0 == OCCUPIED) & (coarse == FREE))


def test_a_large_marginal_does_not_hide_a_broken_one():
    vog = one_submap()
    vog.add_submap(np.eye(4))
    vog.submap(1).integrate_scan([0.1, 0.1, 0.1], [[1.1, 0.1, 0.1]])
    gmap = vj.GlobalMap(CFG, device="cpu")
    gmap.merge(vog)
    marginals = np.tile(np.eye(6), (2, 1, 1))
    marginals[0] *= 1e9
    broken = marginals.copy()
    broken[1, 3, 3] = -1.0  # a variance of -1 m^2: it read as perfectly certain (volume 0)
    with pytest.raises(ValueError, match="marginals must be positive semi-definite"):
        gmap.update_poses(vog, broken)
    skewed = marginals.copy()
    skewed[1, 3, 4] = 0.9  # 90% asymmetric
    with pytest.raises(ValueError, match="marginals must be symmetric"):
        gmap.update_poses(vog, skewed)
    gmap.update_poses(vog, marginals)  # the large one alone is a covariance
    one = np.diag([1e9, 1.0, 1.0, -1.0, 1.0, 1.0])  # and within one matrix
    with pytest.raises(ValueError, match="positive semi-definite"):
        geometry.confidence_volume(one)
    # round-off of a real marginal's size still passes (1e-16 of its largest entry)
    rounded = np.diag([1e9, 1.0, 1.0, 0.0, 1.0, 1.0])
    rounded[3, 3] = -1e-8
    assert geometry.confidence_volume(rounded) == 0.0


def test_set_poses_refuses_a_repeated_id():
    vog = one_submap()
    a, b = np.eye(4), np.eye(4)
    a[0, 3], b[0, 3] = 1.0, 2.0
    with pytest.raises(ValueError, match="ids must not repeat"):
        vog.set_poses([0, 0], [a, b])  # b won silently
    np.testing.assert_array_equal(vog.pose(0), np.eye(4))


def test_global_map_add_names_a_repeat_as_one():
    vog = one_submap()
    with pytest.raises(ValueError, match=r"ids must not repeat a submap, got \[0, 0\]"):
        vj.GlobalMap(CFG, device="cpu").add(vog, [0, 0])


@pytest.mark.parametrize("path", [123, None, 1.5])
def test_from_octomap_refuses_what_is_no_path(path):
    with pytest.raises(ValueError, match="path must be a file path"):
        vj.VoxelMap.from_octomap(path)


def test_from_octomap_reads_a_bytes_path(tmp_path):
    vmap = vj.VoxelMap(CFG, device="cpu")
    vmap.integrate_scan([0.1, 0.1, 0.1], [[1.1, 0.1, 0.1]])
    octomap.save(vmap, tmp_path / "m.bt")
    back = vj.VoxelMap.from_octomap(str(tmp_path / "m.bt").encode())
    np.testing.assert_array_equal(back.voxels()[0], vmap.voxels()[0])


def test_integrate_scan_names_its_origin():
    with pytest.raises(ValueError, match="^origin "):
        vj.VoxelMap(CFG, device="cpu").integrate_scan([1e7, 0.0, 0.0], [[0.0, 0.0, 0.0]])


def test_octomap_save_names_the_file_it_could_not_write(tmp_path):
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.1, max_range=10.0), device="cpu")
    vmap.integrate_scan([4000.0, 0.0, 0.0], [[4001.0, 0.0, 0.0]])  # past 16-bit keys at 0.1 m
    with pytest.raises(ValueError, match="far.bt"):
        octomap.save(vmap, tmp_path / "far.bt")
    assert not (tmp_path / "far.bt").exists()


# ------------------------------------------------------------------ SLAM and the planner


def _box_cloud(rng, n=200):
    return np.concatenate(
        [
            np.c_[rng.uniform(-5, 5, (n, 2)), np.zeros(n)],
            np.c_[rng.uniform(-5, 5, n), np.zeros(n), rng.uniform(0, 3, n)],
            np.c_[np.zeros(n), rng.uniform(-5, 5, n), rng.uniform(0, 3, n)],
        ]
    )


@pytest.mark.parametrize("truth", [np.zeros((4, 4)), 2 * np.eye(4), np.full((4, 4), np.nan), np.eye(3)])
def test_errors_at_centre_refuses_a_pose_that_is_none(truth):
    """A zero or scaled matrix read as no error; NaN passed through."""
    from vogjax.slam import LoopClosure

    closure = LoopClosure(0, 1, np.eye(4), np.eye(6) * 1e-4, None, 0.0, 100, centre=np.array([10.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="T_i_k_true"):
        closure.errors_at_centre(truth)


@pytest.mark.parametrize("normals", ["zero", "nan", "long"])
def test_icp_refuses_a_target_with_normals_that_are_none(normals):
    """Zero normals "converged" where ICP started; NaN ones raised LinAlgError."""
    import dataclasses

    from vogjax.slam import icp, prepare_target

    cloud = _box_cloud(np.random.default_rng(0))
    target = prepare_target(cloud)
    bad = {"zero": 0.0 * target.normals, "nan": np.full_like(target.normals, np.nan), "long": 2 * target.normals}
    with pytest.raises(ValueError, match="normals must be finite unit vectors"):
        icp(cloud, dataclasses.replace(target, normals=bad[normals]), np.eye(4))


def test_icp_batch_checks_its_start_poses_with_no_pairs():
    from vogjax.slam import icp_batch

    with pytest.raises(ValueError, match="T_inits"):
        icp_batch([], [], "garbage")


@pytest.mark.parametrize("kind", ["complex", "bool"])
def test_a_closure_basis_must_be_real(kind):
    """A complex basis lost its imaginary part (a ComplexWarning) and entered the graph."""
    from vogjax.slam import PoseGraph

    graph = PoseGraph()
    graph.add_submap(np.eye(4))
    T = np.eye(4)
    T[0, 3] = 1.0
    graph.add_submap(T, 1.0)
    graph.update()
    basis = np.zeros((6, 1), complex if kind == "complex" else bool)
    basis[3, 0] = 1
    if kind == "complex":
        basis[4, 0] = 5j
    with pytest.raises(ValueError, match="basis"):
        graph.add_loop_closure(0, 1, T, np.eye(6) * 1e-2, basis)
    assert graph.factors[-1][0] == "zpr"


def test_pose_graph_refuses_noise_that_is_no_navnoise():
    from vogjax.slam import PoseGraph

    with pytest.raises(ValueError, match="noise must be a NavNoise"):
        PoseGraph(noise="x")


def test_a_fast_sensors_submaps_enter_the_graph():
    """Submaps of two 5 kHz scans are 0.4 ms apart: the graph refused anything under 1 ms, the
    pipeline stopped midway and its Mapper was left unusable."""
    from vogjax import pipeline
    from vogjax.config import TimingConfig
    from vogjax.io.dataset import ScanBatch

    rng = np.random.default_rng(0)
    scans = 20
    directions = np.tile([[1.0, 0.0, 0.0]], (4, 1)) + rng.normal(0, 0.05, (4, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    poses = np.tile(np.eye(4), (scans, 1, 1))
    poses[:, 0, 3] = np.arange(scans) * 1e-4
    batch = ScanBatch(
        time_s=np.arange(scans) * 2e-4,
        pose_truth=poses,
        pose_nav=poses,
        sonar_origin=np.zeros((scans, 3)),
        sonar_directions=np.tile(directions, (scans, 1, 1)),
        ranges=np.full((scans, 4), 2.0),
        no_return=np.zeros((scans, 4), bool),
        invalid=np.zeros((scans, 4), bool),
        first=0,
    )
    config = pipeline.PipelineConfig(scans_per_submap=2, timing=TimingConfig(every_submaps=0))
    mapper = pipeline.Mapper(config)
    mapper.add(batch)
    mapper.finish_submap()
    assert mapper.graph.num_submaps == mapper.vog.num_submaps == scans // 2
    assert np.all(np.isfinite(mapper.graph.poses()))


def test_planner_arrived_refuses_a_state_that_is_none():
    from vogjax import planner

    nbv = planner.NbvPlanner(planner.PlannerConfig(), bounds=np.array([[-3.0, -3.0, -1.0], [3.0, 3.0, 1.0]]))
    with pytest.raises(ValueError, match="^state "):
        nbv.arrived(np.full(4, np.nan))
    with pytest.raises(ValueError, match="^state "):
        nbv.arrived(np.zeros(3))


@pytest.mark.parametrize("drift_m", ["abc", None, np.array([1.0, 2.0]), True])
def test_planner_refuses_a_drift_that_is_no_number(drift_m):
    from vogjax import planner

    nbv = planner.NbvPlanner(planner.PlannerConfig(), bounds=np.array([[-3.0, -3.0, -1.0], [3.0, 3.0, 1.0]]))
    vmap = vj.VoxelMap(CFG, device="cpu")
    margins = nbv._obstacle_margins
    with pytest.raises(ValueError, match="drift_m"):
        nbv.plan(vmap, np.eye(4), drift_m=drift_m)
    with pytest.raises(ValueError, match="T_world_vehicle"):  # a refused plan leaves the margins
        nbv.plan(vmap, np.full((4, 4), np.nan), drift_m=0.4)
    assert nbv._obstacle_margins == margins


def test_detect_refuses_times_that_do_not_increase():
    from vogjax import slam

    cloud = _box_cloud(np.random.default_rng(1))
    far = np.eye(4)
    far[0, 3] = 30.0
    bounds = (cloud.min(axis=0) - 0.5, cloud.max(axis=0) + 0.5)
    poses = np.stack([np.eye(4), far, np.eye(4)])
    detector = slam.LoopClosureDetector(config=slam.LoopClosureConfig(icp=slam.IcpConfig(free="all")))
    with pytest.raises(ValueError, match="times_s must increase"):  # it blamed radius_m (a NaN bound)
        detector.detect(2, [cloud] * 3, [bounds] * 3, poses, poses, np.array([0.0, 1000.0, 1.0]))


def test_a_candidate_of_one_repeated_point_is_skipped_not_fatal():
    """detect raised "target needs at least 3 distinct points" for one degenerate candidate,
    and lost the closures of the others."""
    from vogjax import slam

    cloud = _box_cloud(np.random.default_rng(2))
    degenerate = np.repeat(cloud[:1], 100, axis=0)
    bounds = (cloud.min(axis=0) - 0.5, cloud.max(axis=0) + 0.5)
    poses = np.tile(np.eye(4), (4, 1, 1))
    detector = slam.LoopClosureDetector(config=slam.LoopClosureConfig(icp=slam.IcpConfig(max_correspondence_m=0.3)))
    times = np.array([0.0, 600.0, 1200.0, 1800.0])
    assert detector.candidates(3, [degenerate, cloud, cloud[:5], cloud], [bounds] * 4, poses) == [1]
    accepted, _ = detector.detect(3, [degenerate, cloud, cloud[:5], cloud], [bounds] * 4, poses, poses, times)
    assert [c.i for c in accepted] == [1]
    assert detector.candidates(3, [cloud, cloud, cloud[:5], degenerate], [bounds] * 4, poses) == []
