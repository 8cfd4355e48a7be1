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
