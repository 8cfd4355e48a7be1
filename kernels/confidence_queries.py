"""Read-only queries of the confidence-rich map: point look-ups of mean and variance, and planner
ray casts that also report the variance met along the ray and the paper's reach probability.

Never-observed voxels (NaN in the mean layer, or no block at all) answer the prior's moments.
"""

import warp as wp

from .hashing import BLOCK_VOXELS, find_voxel_slot, index_in_block, observed
from .traversal import first_boundary, holds_chord, ray_walk_begin, voxel_key, walk_step

wp.set_module_options({"enable_backward": False})


@wp.func
def stored(slot: int, voxel: wp.vec3i, layer: wp.array(dtype=wp.float32)) -> wp.float32:
    if slot < 0:
        return wp.nan
    return layer[slot * BLOCK_VOXELS + index_in_block(voxel)]


@wp.kernel
def lookup_moments(
    points: wp.array(dtype=wp.vec3f),
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    mean: wp.array(dtype=wp.float32),
    variance: wp.array(dtype=wp.float32),
    out_mean: wp.array(dtype=wp.float32),
    out_variance: wp.array(dtype=wp.float32),
):
    """Stored mean and variance of the voxel holding each point; NaN where never observed."""
    tid = wp.tid()
    voxel = voxel_key(points[tid], inv_resolution)
    slot = find_voxel_slot(table_keys, table_slots, voxel)
    out_mean[tid] = stored(slot, voxel, mean)
    out_variance[tid] = stored(slot, voxel, variance)


@wp.kernel
def cast_confidence_rays(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    mean: wp.array(dtype=wp.float32),
    variance: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    prior_variance: wp.float32,
    occupied_threshold: wp.float32,
    free_threshold: wp.float32,
    hit: wp.array(dtype=wp.bool),
    distance: wp.array(dtype=wp.float32),
    num_unknown: wp.array(dtype=wp.int32),
    num_free: wp.array(dtype=wp.int32),
    variance_sum: wp.array(dtype=wp.float32),
    variance_max: wp.array(dtype=wp.float32),
    reach: wp.array(dtype=wp.float32),
):
    """First voxel whose mean reaches occupied_threshold within the range; over the voxels
    before it: how many are unknown or free, the sum and maximum of their variances, and the
    probability that a beam passes them all without bouncing (prod of 1 - mean). Voxels the ray
    only touches at an edge or a corner (holds_chord) are not on it, as in integration."""
    tid = wp.tid()
    max_range = max_ranges[tid]
    w = ray_walk_begin(origins[tid], directions[tid], resolution, inv_resolution, max_range)
    unknown = int(0)
    free = int(0)
    found = bool(False)
    t_hit = max_range
    total = wp.float64(0.0)
    largest = wp.float32(0.0)
    passing = wp.float64(1.0)
    voxel, t_max, t_entry = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    slot = int(-1)
    new_block = bool(True)
    steps = int(0)
    while t_entry < max_range and steps <= w.max_steps:
        if new_block:
            slot = find_voxel_slot(table_keys, table_slots, voxel)
        if holds_chord(t_entry, first_boundary(t_max, max_range), resolution):
            m = stored(slot, voxel, mean)
            v = stored(slot, voxel, variance)
            if not observed(m):
                m = prior_mean
                v = prior_variance
                unknown += 1
            elif m >= occupied_threshold:
                found = True
                t_hit = t_entry
                break
            elif m <= free_threshold:
                free += 1
            else:
                unknown += 1
            total = total + wp.float64(v)
            largest = wp.max(largest, v)
            passing = passing * (wp.float64(1.0) - wp.float64(m))
        voxel, t_max, t_entry, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
    hit[tid] = found
    distance[tid] = wp.float32(t_hit)
    num_unknown[tid] = unknown
    num_free[tid] = free
    variance_sum[tid] = wp.float32(total)
    variance_max[tid] = largest
    reach[tid] = wp.float32(passing)


@wp.kernel
def find_likely_causes(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    mean: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    ranges: wp.array(dtype=wp.float64),
):
    """The most probable cause of a reading along each ray (Eqs. 14-16: bounce times reach,
    the cause at infinity included): the middle of its chord, or -1 for "no return"."""
    tid = wp.tid()
    max_range = max_ranges[tid]
    w = ray_walk_begin(origins[tid], directions[tid], resolution, inv_resolution, max_range)
    best = wp.float64(-1.0)
    best_probability = wp.float64(-1.0)
    passing = wp.float64(1.0)
    voxel, t_max, t_in = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    slot = int(-1)
    new_block = bool(True)
    steps = int(0)
    while t_in < max_range and steps <= w.max_steps:
        if new_block:
            slot = find_voxel_slot(table_keys, table_slots, voxel)
        t_out = first_boundary(t_max, max_range)
        if holds_chord(t_in, t_out, resolution):
            m = stored(slot, voxel, mean)
            if not observed(m):
                m = prior_mean
            probability = wp.float64(m) * passing
            if probability > best_probability:
                best_probability = probability
                best = wp.float64(0.5) * (t_in + t_out)
            passing = passing * (wp.float64(1.0) - wp.float64(m))
        voxel, t_max, t_in, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
    if passing > best_probability:
        best = wp.float64(-1.0)
    ranges[tid] = best


@wp.func
def voxel_cost(
    slot: int,
    voxel: wp.vec3i,
    mean: wp.array(dtype=wp.float32),
    variance: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    prior_variance: wp.float32,
) -> wp.float64:
    """mean + variance of a voxel, the prior's where never observed."""
    m = stored(slot, voxel, mean)
    v = stored(slot, voxel, variance)
    if not observed(m):
        m = prior_mean
        v = prior_variance
    return wp.float64(m) + wp.float64(v)


@wp.kernel
def sum_segment_costs(
    starts: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    lengths: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    mean: wp.array(dtype=wp.float32),
    variance: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    prior_variance: wp.float32,
    costs: wp.array(dtype=wp.float64),
):
    """Sum of mean + variance (Eq. 34) over every voxel a segment passes (holds_chord). A segment
    that passes none (a point, or one too short to hold a chord on either side of a plane) costs
    the voxel it starts in."""
    tid = wp.tid()
    length = lengths[tid]
    w = ray_walk_begin(starts[tid], directions[tid], resolution, inv_resolution, length)
    total = wp.float64(0.0)
    passed = int(0)
    voxel, t_max, t_in = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    slot = int(-1)
    new_block = bool(True)
    steps = int(0)
    while t_in < length and steps <= w.max_steps:
        if new_block:
            slot = find_voxel_slot(table_keys, table_slots, voxel)
        t_out = first_boundary(t_max, length)
        if holds_chord(t_in, t_out, resolution):
            total = total + voxel_cost(slot, voxel, mean, variance, prior_mean, prior_variance)
            passed += 1
        voxel, t_max, t_in, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
    if passed == 0:
        total = voxel_cost(
            find_voxel_slot(table_keys, table_slots, w.voxel), w.voxel, mean, variance, prior_mean, prior_variance
        )
    costs[tid] = total
