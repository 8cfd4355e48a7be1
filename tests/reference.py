"""Brute-force NumPy/Python reference of OctoMap's update rule and of ray queries.

Written independently of the Warp kernels, one voxel at a time, for small test inputs.
Arithmetic follows OctoMap: float32 beam geometry, float64 boundary distances.
"""

import math

import numpy as np

f32 = np.float32


def key_of(point, voxel_size):
    inv = 1.0 / voxel_size
    return tuple(int(math.floor(float(c) * inv)) for c in point)


def _norm32(d):
    s = f32(d[0] * d[0]) + f32(d[1] * d[1])
    s = f32(s + f32(d[2] * d[2]))
    return math.sqrt(float(s))


def segment_keys(origin, end, voxel_size):
    """OctoMap computeRayKeys: the voxels from origin's up to, not including, end's."""
    origin = origin.astype(f32)
    end = end.astype(f32)
    k0, k1 = key_of(origin, voxel_size), key_of(end, voxel_size)
    if k0 == k1:
        return []
    d = (end - origin).astype(f32)
    length = f32(_norm32(d))
    direction = (d / length).astype(f32)
    step, t_max, t_delta = [0, 0, 0], [math.inf] * 3, [math.inf] * 3
    for i in range(3):
        if direction[i] != 0:
            step[i] = 1 if direction[i] > 0 else -1
            border = (k0[i] + 0.5) * voxel_size + float(f32(step[i] * voxel_size * 0.5))
            t_max[i] = (border - float(origin[i])) / float(direction[i])
            t_delta[i] = voxel_size / abs(float(direction[i]))
    keys, key = [k0], list(k0)
    while True:
        dim = _octomap_dim(t_max)
        key[dim] += step[dim]
        t_max[dim] += t_delta[dim]
        if tuple(key) == k1 or min(t_max) > float(length):
            return keys
        keys.append(tuple(key))


def _octomap_dim(t):
    if t[0] < t[1]:
        return 0 if t[0] < t[2] else 2
    return 1 if t[1] < t[2] else 2


def insert_scan(cells, origin, points, cfg):
    """Update the dict `cells` (voxel key -> float32 log-odds) with one scan, OctoMap-style."""
    origin = np.asarray(origin, f32)
    free, occupied = set(), set()
    for p in np.asarray(points, f32):
        d = (p - origin).astype(f32)
        norm = _norm32(d)
        if norm <= cfg.max_range:
            free.update(segment_keys(origin, p, cfg.voxel_size))
            occupied.add(key_of(p, cfg.voxel_size))
        else:
            direction = (d / f32(norm)).astype(f32)
            end = (origin + (direction * f32(cfg.max_range)).astype(f32)).astype(f32)
            free.update(segment_keys(origin, end, cfg.voxel_size))
    for keys, update in ((free - occupied, cfg.log_miss), (occupied, cfg.log_hit)):
        for k in keys:
            v = f32(cells.get(k, f32(0.0)) + update)
            cells[k] = min(max(v, cfg.log_clamp_min), cfg.log_clamp_max)


def state_of(value, cfg):
    if value is None:
        return 0
    if value >= cfg.log_occupied:
        return 2
    if value <= cfg.log_free:
        return 1
    return 0


def raycast(cells, origin, direction, max_range, cfg):
    """(hit, distance, num_unknown, num_free) of one ray: plain Amanatides-Woo in float64."""
    s = cfg.voxel_size
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    key = list(key_of(o, s))
    step = [int(np.sign(c)) for c in d]
    t_max = [((key[i] + (step[i] > 0)) * s - o[i]) / d[i] if step[i] else math.inf for i in range(3)]
    t_delta = [s / abs(d[i]) if step[i] else math.inf for i in range(3)]
    t, unknown, free = 0.0, 0, 0
    while t < max_range:
        state = state_of(cells.get(tuple(key)), cfg)
        if state == 2:
            return True, t, unknown, free
        free += state == 1
        unknown += state == 0
        dim = _octomap_dim(t_max)
        t = t_max[dim]
        key[dim] += step[dim]
        t_max[dim] += t_delta[dim]
    return False, max_range, unknown, free


def line_values(cells, start, end, cfg):
    keys = segment_keys(np.asarray(start), np.asarray(end), cfg.voxel_size)
    keys.append(key_of(np.asarray(end, f32), cfg.voxel_size))
    return [float(cells.get(k, 0.0)) for k in keys]


def random_scans(rng, num_scans, beams, spread=4.0, far=0.0):
    """Origins (S,3) and endpoints (S*beams,3) float32; a fraction `far` of beams overshoots 11 m."""
    origins = rng.uniform(-1.0, 1.0, (num_scans, 3)).astype(f32)
    directions = rng.normal(size=(num_scans * beams, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ranges = rng.uniform(0.05, spread, num_scans * beams)
    ranges[rng.random(num_scans * beams) < far] = rng.uniform(11.5, 14.0)
    points = np.repeat(origins, beams, axis=0) + directions * ranges[:, None]
    return origins, points.astype(f32), np.repeat(np.arange(num_scans), beams)
