"""Random submaps for tests, and a brute-force NumPy reference of the virtual/global map sums."""

import numpy as np

import vogjax as vj

from . import reference as ref

SCALE = 2.0**24


def random_pose(rng, spread=2.0, tilt=0.3):
    yaw, pitch, roll = rng.uniform(-np.pi, np.pi), rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt)
    cz, sz, cy, sy, cx, sx = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    pose = np.eye(4)
    pose[:3, :3] = rz @ ry @ rx
    pose[:3, 3] = rng.uniform(-spread, spread, 3)
    return pose


def random_vog(rng, num_submaps, cfg=None, scans=2, beams=60, spread=2.5):
    cfg = cfg or vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vog = vj.VogMap(cfg)
    for _ in range(num_submaps):
        i = vog.add_submap(random_pose(rng))
        vog.submap(i).integrate_scans(*ref.random_scans(rng, scans, beams, spread=spread, far=0.1))
    return vog


def fixed_point(values):
    scaled = np.asarray(values, np.float64) * SCALE
    return (np.sign(scaled) * np.floor(np.abs(scaled) + 0.5)).astype(np.int64)  # half away from 0


def submap_cells(submap):
    centres, values = submap.voxels()
    keys = np.floor(centres / submap.config.voxel_size).astype(np.int64)
    return {tuple(k): v for k, v in zip(keys.tolist(), values)}


def reference_sums(vog, points):
    """Per point: fixed-point sum and count over submaps of the voxel holding it (brute force)."""
    s = vog.config.voxel_size
    sums = np.zeros(len(points), np.int64)
    counts = np.zeros(len(points), np.int32)
    for i in range(vog.num_submaps):
        cells = submap_cells(vog.submap(i))
        pose = vog.pose(i)
        local = (points - pose[:3, 3]) @ pose[:3, :3]  # R^T (p - t), row-wise
        keys = np.floor(local * (1.0 / s)).astype(np.int64)
        for n, key in enumerate(map(tuple, keys.tolist())):
            if key in cells:
                sums[n] += fixed_point(cells[key])
                counts[n] += 1
    return sums, counts


def reference_values(vog, points):
    sums, counts = reference_sums(vog, points)
    cfg = vog.config
    values = np.clip((sums / SCALE).astype(np.float32), cfg.log_clamp_min, cfg.log_clamp_max)
    values[counts == 0] = np.nan
    return values


def reference_merge(vog):
    """{global voxel key: (sum, count)} of a full merge, from every voxel near every submap."""
    s = vog.config.voxel_size
    result = {}
    for i in range(vog.num_submaps):
        box = vog.submap(i).bounds()
        if box is None:
            continue
        pose = vog.pose(i)
        corners = np.array(
            [[x, y, z] for x in (box[0][0], box[1][0]) for y in (box[0][1], box[1][1]) for z in (box[0][2], box[1][2])]
        )
        world = corners @ pose[:3, :3].T + pose[:3, 3]
        lo = np.floor(world.min(axis=0) / s).astype(int) - 1
        hi = np.floor(world.max(axis=0) / s).astype(int) + 1
        grid = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1)
        keys = grid.reshape(-1, 3)
        centres = (keys + 0.5) * s
        cells = submap_cells(vog.submap(i))
        local = np.floor(((centres - pose[:3, 3]) @ pose[:3, :3]) * (1.0 / s)).astype(np.int64)
        for key, pulled in zip(map(tuple, keys.tolist()), map(tuple, local.tolist())):
            if pulled in cells:
                total, count = result.get(key, (0, 0))
                result[key] = (total + int(fixed_point(cells[pulled])), count + 1)
    return result
