"""VogMap bookkeeping: submaps, poses, derived boxes and clouds, bad input."""

import numpy as np
import pytest

import vogjax as vj

from . import reference as ref
from .submap_helpers import random_pose


def test_poses_round_trip_and_only_poses_change():
    rng = np.random.default_rng(0)
    vog = vj.VogMap(vj.MapConfig(voxel_size=0.2))
    poses = np.stack([random_pose(rng) for _ in range(3)])
    assert [vog.add_submap(p) for p in poses] == [0, 1, 2] and vog.num_submaps == 3
    vog.submap(1).integrate_scans(*ref.random_scans(rng, 2, 50))
    contents = vog.submap(1).voxels()
    np.testing.assert_array_equal(vog.poses(), poses)
    new = np.stack([random_pose(rng) for _ in range(2)])
    vog.set_poses([2, 1], new)
    np.testing.assert_array_equal(vog.pose(1), new[1])
    np.testing.assert_array_equal(vog.poses([0, 2]), np.stack([poses[0], new[0]]))
    after = vog.submap(1).voxels()
    assert np.array_equal(contents[0], after[0]) and np.array_equal(contents[1], after[1])


def test_bounds_and_occupied_points_follow_integration():
    vog = vj.VogMap(vj.MapConfig(voxel_size=0.1))
    i = vog.add_submap(np.eye(4))
    submap = vog.submap(i)
    assert submap.bounds() is None and len(submap.occupied_points()) == 0
    origin = np.array([0.05, 0.05, 0.05])
    wall = np.array([[2.05, 0.05, 0.05], [2.05, 0.15, 0.05]])
    for _ in range(3):
        submap.integrate_scan(origin, wall)
    lo, hi = submap.bounds()
    np.testing.assert_allclose(lo, [0.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(hi, [2.1, 0.2, 0.1], atol=1e-9)
    np.testing.assert_allclose(submap.occupied_points(), wall, atol=1e-9)
    submap.integrate_scan(origin, [[-1.05, 0.05, 0.05]] * 3)
    assert submap.bounds()[0][0] == pytest.approx(-1.1)


def test_empty_vog_answers_unknown():
    vog = vj.VogMap()
    assert vog.state(np.zeros((2, 3))).tolist() == [vj.UNKNOWN] * 2
    r = vog.raycast(np.full((1, 3), 0.05), [[0, 0, 1.0]], 1.0)
    assert not r.hit[0] and r.num_unknown[0] == 11  # its own voxel, then ten entered by 0.95 m


@pytest.mark.parametrize(
    "call, argument",
    [
        (lambda v: v.add_submap(np.eye(3)), "pose"),
        (lambda v: v.add_submap(np.diag([1.0, 1.0, -1.0, 1.0])), "pose"),
        (lambda v: v.add_submap(np.diag([2.0, 1.0, 1.0, 1.0])), "pose"),
        (lambda v: v.add_submap(np.full((4, 4), np.nan)), "pose"),
        (lambda v: v.set_poses([5], np.eye(4)[None]), "ids"),
        (lambda v: v.set_poses([-1], np.eye(4)[None]), "ids"),
        (lambda v: v.set_poses([0, 1], np.eye(4)[None]), "poses"),
        (lambda v: v.set_poses([0], np.ones((1, 4, 4))), "poses"),
        (lambda v: v.submap(2), "i"),
        (lambda v: v.poses([0.5]), "ids"),
        (lambda v: v.state(np.full((1, 3), np.inf)), "points"),
        (lambda v: v.raycast(np.zeros((1, 3)), np.zeros((1, 3)), 1.0), "directions"),
    ],
)
def test_bad_input(call, argument):
    vog = vj.VogMap()
    vog.add_submap(np.eye(4))
    vog.add_submap(np.eye(4))
    before = vog.poses()
    with pytest.raises(ValueError, match=argument):
        call(vog)
    np.testing.assert_array_equal(vog.poses(), before)
    assert vog.num_submaps == 2


def test_view_shares_submaps_at_other_poses():
    rng = np.random.default_rng(3)
    vog = vj.VogMap(vj.MapConfig(voxel_size=0.2))
    for _ in range(3):
        vog.submap(vog.add_submap(random_pose(rng))).integrate_scans(*ref.random_scans(rng, 1, 30))
    moved = np.stack([random_pose(rng) for _ in range(2)])
    view = vog.view([2, 0], moved)
    assert view.submap(0) is vog.submap(2) and view.num_submaps == 2
    np.testing.assert_array_equal(view.poses(), moved)
    np.testing.assert_array_equal(vog.pose(2), vog.poses()[2])  # the original keeps its poses
    points = (vog.submap(2).voxels()[0] @ moved[0][:3, :3].T + moved[0][:3, 3])[:50]
    lone = vj.VogMap(vog.config)
    lone._submaps, lone._poses = [vog.submap(2)], moved[:1]
    np.testing.assert_array_equal(vj.VogMap.view(vog, [2], moved[:1]).log_odds(points), lone.log_odds(points))
