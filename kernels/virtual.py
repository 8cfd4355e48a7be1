"""Virtual-map queries: the sum over submaps, evaluated on the fly (Ho et al.'s VOG-map).

Each submap is described by a `SubmapView` (`submap_view.py`); kernels run over (query, submap)
pairs and skip pairs whose box the query misses.
Values pull exactly like the global map (kernels/accumulation.py), so at voxel centres the
virtual map and the global map agree bit for bit.
"""

import warp as wp

from .fixed_point import from_fixed_point, to_fixed_point
from .hashing import VOXEL_KEY_LIMIT_C, observed
from .submap_view import SubmapView, submap_value, voxel_centre
from .traversal import (
    FAR,
    l1_distance,
    ray_entry,
    ray_key_range,
    ray_voxel_at,
    ray_voxels_until,
    ray_walk_begin,
    ray_walk_resume,
    walk_step,
)

# A stretch of unknown voxels longer than this is counted in closed form, not walked.
SKIP_VOXELS = wp.constant(64)

wp.set_module_options({"enable_backward": False})


@wp.kernel
def sum_at_points(
    points: wp.array(dtype=wp.vec3d),
    first: int,
    views: wp.array(dtype=SubmapView),
    inv_resolution: wp.float64,
    sums: wp.array(dtype=wp.int64),
    counts: wp.array(dtype=wp.int32),
):
    """Over (point, submap) pairs: fixed-point sum and count of the submaps observing each point."""
    q, i = wp.tid()
    q = q + first
    value = submap_value(views[i], points[q], inv_resolution)
    if observed(value):
        wp.atomic_add(sums, q, to_fixed_point(value))
        wp.atomic_add(counts, q, 1)


@wp.func
def ray_box_interval(view: SubmapView, origin: wp.vec3d, direction: wp.vec3d, max_range: wp.float64) -> wp.vec2d:
    """[t_in, t_out] of the ray inside the submap's box, clipped to [0, max_range] (empty: t_in > t_out)."""
    o = view.rotation_t * (origin - view.translation)
    d = view.rotation_t * direction
    t_in = wp.float64(0.0)
    t_out = max_range
    for axis in range(3):
        if wp.abs(d[axis]) < wp.float64(1e-15):
            if o[axis] < view.box_lo[axis] or o[axis] > view.box_hi[axis]:
                return wp.vec2d(wp.float64(1.0), wp.float64(0.0))
        else:
            a = (view.box_lo[axis] - o[axis]) / d[axis]
            b = (view.box_hi[axis] - o[axis]) / d[axis]
            t_in = wp.max(t_in, wp.min(a, b))
            t_out = wp.min(t_out, wp.max(a, b))
    return wp.vec2d(t_in, t_out)


@wp.kernel
def count_ray_candidates(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    first: int,
    views: wp.array(dtype=SubmapView),
    counts: wp.array(dtype=wp.int32),
):
    r, i = wp.tid()
    r = r + first
    span = ray_box_interval(views[i], origins[r], directions[r], max_ranges[r])
    if span[0] <= span[1]:
        wp.atomic_add(counts, r, 1)


@wp.kernel
def list_ray_candidates(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    first: int,
    views: wp.array(dtype=SubmapView),
    offsets: wp.array(dtype=wp.int32),
    fill: wp.array(dtype=wp.int32),
    candidates: wp.array(dtype=wp.int32),
    spans: wp.array(dtype=wp.vec2d),
):
    r, i = wp.tid()
    r = r + first
    span = ray_box_interval(views[i], origins[r], directions[r], max_ranges[r])
    if span[0] <= span[1]:
        k = offsets[r] + wp.atomic_add(fill, r, 1)
        candidates[k] = i
        spans[k] = span


@wp.kernel
def cast_virtual_rays(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    first: int,
    views: wp.array(dtype=SubmapView),
    offsets: wp.array(dtype=wp.int32),
    candidates: wp.array(dtype=wp.int32),
    spans: wp.array(dtype=wp.vec2d),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    clamp_min: wp.float32,
    clamp_max: wp.float32,
    log_occupied: wp.float32,
    log_free: wp.float32,
    hit: wp.array(dtype=wp.bool),
    distance: wp.array(dtype=wp.float32),
    num_unknown: wp.array(dtype=wp.int32),
    num_free: wp.array(dtype=wp.int32),
):
    """Walk the world voxel grid; at each voxel centre sum the candidate submaps the ray is in.

    Before the first candidate's span and after the last one every voxel is unknown: long
    stretches there are skipped and counted in closed form (as cast_rays does), and voxels
    outside the key range are not counted.
    """
    r = wp.tid() + first
    origin, direction = origins[r], directions[r]
    max_range = max_ranges[r]
    w = ray_walk_begin(origin, direction, resolution, inv_resolution, max_range)
    step, t_delta = w.step, w.t_delta
    t_end = wp.min(max_range, ray_key_range(origin, direction, resolution, VOXEL_KEY_LIMIT_C))
    known_from = FAR
    known_to = wp.float64(-1.0)
    for k in range(offsets[r], offsets[r + 1]):
        known_from = wp.min(known_from, spans[k][0])
        known_to = wp.max(known_to, spans[k][1])
    # spans come from boxes widened by a voxel: voxels entered outside [known_from, known_to]
    # lie outside every candidate's box
    voxel, t_max, t_entry = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    unknown = int(0)
    free = int(0)
    found = bool(False)
    t_hit = max_range
    steps = int(0)
    before_checked = bool(False)
    after_checked = bool(False)
    while t_entry < t_end and steps <= w.max_steps:
        if t_entry > known_to and not after_checked:
            after_checked = True
            n = ray_voxels_until(origin, direction, voxel, step, resolution, inv_resolution, t_end)
            if n > SKIP_VOXELS:
                unknown += n
                break
        elif t_entry < known_from and known_from < t_end and not before_checked:
            before_checked = True
            target = ray_voxel_at(origin, direction, voxel, step, inv_resolution, known_from)
            skipped = l1_distance(voxel, target)
            if skipped > SKIP_VOXELS:
                unknown += skipped
                steps += skipped
                t_entry = ray_entry(origin, direction, voxel, target, step, resolution)
                voxel = target
                t_max = ray_walk_resume(origin, direction, voxel, step, resolution)
                continue
        t_exit = wp.min(wp.min(t_max[0], t_max[1]), t_max[2])
        centre = voxel_centre(voxel, resolution)
        total = wp.int64(0)
        count = wp.int32(0)
        for k in range(offsets[r], offsets[r + 1]):
            span = spans[k]
            if t_exit >= span[0] and t_entry <= span[1]:
                value = submap_value(views[candidates[k]], centre, inv_resolution)
                if observed(value):
                    total += to_fixed_point(value)
                    count += 1
        value = from_fixed_point(total, count, clamp_min, clamp_max)
        if value >= log_occupied:
            found = True
            t_hit = t_entry
            break
        if value <= log_free:
            free += 1
        else:
            unknown += 1
        voxel, t_max, t_entry, _new_block = walk_step(voxel, step, t_max, t_delta)
        steps += 1
    hit[r] = found
    distance[r] = wp.float32(t_hit)
    num_unknown[r] = unknown
    num_free[r] = free
