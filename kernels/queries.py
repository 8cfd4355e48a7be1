"""Read-only queries: point look-ups, planner ray casts and line queries.

Unobserved voxels hold NaN in the voxel pool; look-ups outside the table answer NaN too.
"""

import warp as wp

from .hashing import (
    BLOCK_VOXELS,
    EMPTY_KEY,
    find_voxel_slot,
    grid_slot,
    index_in_block,
    observed,
    unpack_block,
)
from .integration import walk_of_beam
from .traversal import (
    FAR,
    VoxelWalk,
    l1_distance,
    ray_box_span,
    ray_entry,
    ray_key_range,
    ray_voxel_at,
    ray_voxels_until,
    ray_walk_begin,
    ray_walk_resume,
    segment_continues,
    unit_direction,
    voxel_key,
    walk_step,
)

wp.set_module_options({"enable_backward": False})


@wp.func
def value_in_slot(slot: int, voxel: wp.vec3i, log_odds: wp.array(dtype=wp.float32)) -> wp.float32:
    if slot < 0:
        return wp.nan
    return log_odds[slot * BLOCK_VOXELS + index_in_block(voxel)]


@wp.func
def voxel_state(value: wp.float32, log_occupied: wp.float32, log_free: wp.float32) -> wp.uint32:
    """0 unknown, 1 free, 2 occupied."""
    if value >= log_occupied:  # NaN (never observed) fails both comparisons: unknown
        return wp.uint32(2)
    if value <= log_free:
        return wp.uint32(1)
    return wp.uint32(0)


@wp.kernel
def classify_blocks(
    log_odds: wp.array(dtype=wp.float32),
    log_occupied: wp.float32,
    log_free: wp.float32,
    states: wp.array(dtype=wp.uint32),
):
    """states[slot * 32 + w]: the states of voxels 16 w .. 16 w + 15 of block `slot`, two bits
    each (0 unknown, 1 free, 2 occupied): what a ray cast needs, in an eighth of the bytes."""
    tid = wp.tid()
    word = wp.uint32(0)
    for v in range(16):
        word = word | (voxel_state(log_odds[tid * 16 + v], log_occupied, log_free) << wp.uint32(2 * v))
    states[tid] = word


@wp.func
def packed_state(states: wp.array(dtype=wp.uint32), base: int, i: int) -> int:
    """State of voxel i (index_in_block) of the block whose words start at states[base]:
    0 unknown, 1 free, 2 occupied (classify_blocks)."""
    # the index masked to 31 bits (it is never negative): Warp then drops its negative-index test
    return int((states[(base + (i >> 4)) & 0x7FFFFFFF] >> wp.uint32((i & 15) << 1)) & wp.uint32(3))


@wp.func
def known_or_zero(value: wp.float32) -> wp.float32:
    return wp.where(observed(value), value, wp.float32(0.0))


@wp.kernel
def lookup_log_odds(
    points: wp.array(dtype=wp.vec3f),
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    log_odds: wp.array(dtype=wp.float32),
    values: wp.array(dtype=wp.float32),
):
    tid = wp.tid()
    voxel = voxel_key(points[tid], inv_resolution)
    values[tid] = value_in_slot(find_voxel_slot(table_keys, table_slots, voxel), voxel, log_odds)


# What check_rays finds wrong with a ray, as indices of its `first_bad` output.
BAD_ORIGIN = wp.constant(0)  # NaN, infinite, or beyond the key range
BAD_DIRECTION = wp.constant(1)  # NaN, infinite or zero
BAD_RANGE = wp.constant(2)  # NaN, infinite or not positive


@wp.func
def finite3(v: wp.vec3d) -> bool:
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])


@wp.kernel
def check_rays(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    voxel_size: wp.float64,
    key_limit: wp.float64,
    first_bad: wp.array(dtype=wp.int32),
):
    """The host checks of `BlockMap.raycast` for rays already on the device: first_bad[k], set
    to the ray count beforehand, ends as the index of the first ray with fault k (BAD_*).
    max_ranges holds one range per ray, or one for all. An origin is out of range as
    `within_key_range` decides, in the same float64 operations: max |o| / voxel_size >= key_limit."""
    tid = wp.tid()
    o = origins[tid]
    if not finite3(o) or wp.max(wp.abs(o[0]), wp.max(wp.abs(o[1]), wp.abs(o[2]))) / voxel_size >= key_limit:
        wp.atomic_min(first_bad, BAD_ORIGIN, tid)
    d = directions[tid]
    if not finite3(d) or (d[0] == wp.float64(0.0) and d[1] == wp.float64(0.0) and d[2] == wp.float64(0.0)):
        wp.atomic_min(first_bad, BAD_DIRECTION, tid)
    r = max_ranges[wp.min(tid, max_ranges.shape[0] - 1)]
    if not (wp.isfinite(r) and r > wp.float64(0.0)):
        wp.atomic_min(first_bad, BAD_RANGE, tid)


# A stretch of unknown voxels longer than this is skipped and counted in closed form, not
# walked. Past the map's box, where nothing can be hit, a coarse level counts a stretch of more
# than SKIP_VOXELS_COARSE (the host passes it as count_after): its voxels are 2^k times as long,
# and 64 of them are longer than any planner ray. Before the box the walk resumes from
# recomputed boundaries, which can break a tie at a voxel edge the other way than a walk: there
# every level keeps SKIP_VOXELS, so only rays from that far off see it.
SKIP_VOXELS = wp.constant(64)
SKIP_VOXELS_COARSE = 4


@wp.struct
class RayCastStart:
    """Where a ray cast's walk begins, past any long unknown stretch before the map's box, with
    the constants it steps by (ray_cast_start)."""

    voxel: wp.vec3i
    t_max: wp.vec3d
    t_delta: wp.vec3d
    step: wp.vec3i
    t_entry: wp.float64  # distance at which the walk enters `voxel`
    t_end: wp.float64  # the range, or where the ray leaves the key range if that is nearer
    t_after: wp.float64  # the ray is past the map's box (widened by a voxel) after this
    max_steps: int
    skipped: int  # unknown voxels before `voxel` counted without walking them


@wp.func
def ray_cast_start(
    origin: wp.vec3d,
    direction: wp.vec3d,
    max_range: wp.float64,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    known_lo: wp.vec3i,
    known_hi: wp.vec3i,
    key_limit: int,
) -> RayCastStart:
    """The start of a ray cast along unit `direction` over a map whose known voxels all lie in
    [known_lo, known_hi] (voxel coordinates; hi < lo: none). Every voxel outside that box
    (widened by a voxel) is unknown, so a stretch of more than SKIP_VOXELS voxels before it is
    skipped and counted. The walk ends where the ray leaves the key range, [-key_limit,
    key_limit) voxels of this size per axis: VOXEL_KEY_LIMIT >> level, the same metres at every
    level (no coarse walk counts voxels no level-0 key can name).

    Every ray pays this once, whatever it walks after, so the common cases take a shorter way
    to the same bits: a ray that cannot leave the key range within its range has its range as
    its end (no distance to the key range's faces), and a ray starting in the map's box has no
    stretch before it, so only its distance to the box's exit faces is needed."""
    w = ray_walk_begin(origin, direction, resolution, inv_resolution, max_range)
    lo = wp.vec3d(wp.float64(known_lo[0] - 1), wp.float64(known_lo[1] - 1), wp.float64(known_lo[2] - 1))
    hi = wp.vec3d(wp.float64(known_hi[0] + 2), wp.float64(known_hi[1] + 2), wp.float64(known_hi[2] + 2))
    lo = lo * resolution
    hi = hi * resolution
    s = RayCastStart()
    s.voxel = w.voxel
    s.t_max = w.t_max
    s.t_delta = w.t_delta
    s.step = w.step
    s.t_entry = wp.float64(0.0)
    s.max_steps = w.max_steps
    s.skipped = 0
    # Every face of the key range lies more than twice the range beyond |origin| + range, so
    # each distance to one exceeds the range (a unit direction's components are at most 1 + a
    # few ulps): ray_key_range could only give a larger end, and the minimum is the range.
    reach = wp.max(wp.max(wp.abs(origin[0]), wp.abs(origin[1])), wp.abs(origin[2])) + max_range
    if reach + reach < wp.float64(key_limit) * resolution:
        s.t_end = max_range
    else:
        s.t_end = wp.min(max_range, ray_key_range(origin, direction, resolution, key_limit))
    inside = (
        known_hi[0] >= known_lo[0]
        and origin[0] >= lo[0]
        and origin[0] <= hi[0]
        and origin[1] >= lo[1]
        and origin[1] <= hi[1]
        and origin[2] >= lo[2]
        and origin[2] <= hi[2]
    )
    if inside:  # ray_box_span's t_out: per axis the larger of its two distances, the exit face's
        t_out = FAR
        for i in range(3):
            face = wp.where(direction[i] > wp.float64(0.0), hi[i], lo[i])
            t_out = wp.where(direction[i] != wp.float64(0.0), wp.min(t_out, (face - origin[i]) / direction[i]), t_out)
        s.t_after = t_out
        return s
    span = ray_box_span(origin, direction, lo, hi)
    if known_hi[0] < known_lo[0] or span[0] > span[1]:
        span = wp.vec2d(wp.float64(-1.0), wp.float64(-1.0))  # no known voxel on the ray: all after
    s.t_after = span[1]
    if span[0] > wp.float64(0.0) and span[0] < s.t_end:  # a long unknown stretch before the map: skip it
        target = ray_voxel_at(origin, direction, w.voxel, w.step, inv_resolution, span[0])
        skipped = l1_distance(w.voxel, target)
        if skipped > SKIP_VOXELS:
            s.skipped = skipped
            s.t_entry = ray_entry(origin, direction, w.voxel, target, w.step, resolution)
            s.voxel = target
            s.t_max = ray_walk_resume(origin, direction, target, w.step, resolution)
    return s


@wp.kernel
def cast_rays(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_ranges: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    grid_lo: wp.vec3i,
    known_lo: wp.vec3i,
    known_hi: wp.vec3i,
    count_after: int,
    key_limit: int,
    grid_dims: wp.vec3i,
    grid: wp.array(dtype=wp.int32),
    states: wp.array(dtype=wp.uint32),
    hit: wp.array(dtype=wp.bool),
    distance: wp.array(dtype=wp.float32),
    num_unknown: wp.array(dtype=wp.int32),
    num_free: wp.array(dtype=wp.int32),
):
    """First OCCUPIED voxel along each ray (directions of any nonzero length) within its range
    (max_ranges: one per ray, or one for all), and the FREE and UNKNOWN voxels passed before it.

    Voxel states come from classify_blocks. A block is looked up on entering it, in the dense
    grid (its first block at grid_lo) when grid_dims > 0 (one load), else in the hash table.
    Every known voxel lies in [known_lo, known_hi] (voxel coordinates): outside that box a ray
    skips a stretch of more than SKIP_VOXELS before it (`ray_cast_start`) and counts one of more
    than `count_after` after it (`ray_voxels_until`) without walking, so its cost is bounded by
    the map, not the range.
    Voxels outside the key range are not counted. The GPU's kernel; on a CPU,
    cast_rays_on_grid answers the same.
    """
    tid = wp.tid()
    origin, direction = origins[tid], unit_direction(directions[tid])
    max_range = max_ranges[wp.where(max_ranges.shape[0] == 1, 0, tid)]  # one range: for every ray
    s = ray_cast_start(origin, direction, max_range, resolution, inv_resolution, known_lo, known_hi, key_limit)
    # walk_step's choice, on scalars (a struct copied every step costs several times the step)
    voxel, t_max, t_delta, step = s.voxel, s.t_max, s.t_delta, s.step
    x, y, z = voxel[0], voxel[1], voxel[2]
    tx, ty, tz = t_max[0], t_max[1], t_max[2]
    dx, dy, dz = t_delta[0], t_delta[1], t_delta[2]
    sx, sy, sz = step[0], step[1], step[2]
    t_entry, t_end, t_after = wp.float64(s.t_entry), wp.float64(s.t_end), wp.float64(s.t_after)
    max_steps = int(s.max_steps)
    unknown = int(s.skipped)
    steps = int(s.skipped)
    free = int(0)
    found = bool(False)
    t_hit = max_range
    base = int(-1)  # states index of the current block; -1: no block there
    block = wp.vec3i(x >> 3, y >> 3, z >> 3)
    looked_up = bool(False)
    dense = grid_dims[0] > 0
    while t_entry < t_end and steps <= max_steps:
        if t_entry > t_after:  # past the map: count the rest of a long stretch
            t_after = FAR
            n = ray_voxels_until(origin, direction, wp.vec3i(x, y, z), step, resolution, inv_resolution, t_end)
            if n > count_after:
                unknown += n
                break
        if not looked_up or (x >> 3) != block[0] or (y >> 3) != block[1] or (z >> 3) != block[2]:
            block = wp.vec3i(x >> 3, y >> 3, z >> 3)
            looked_up = True
            slot = int(-1)
            if dense:
                slot = grid_slot(block, grid_lo, grid_dims, grid)
            else:
                slot = find_voxel_slot(table_keys, table_slots, wp.vec3i(x, y, z))
            base = wp.where(slot < 0, -1, slot * 32)
        state = int(0)
        if base >= 0:
            state = packed_state(states, base, ((x & 7) << 6) | ((y & 7) << 3) | (z & 7))
        if state == 2:
            found = True
            t_hit = t_entry
            break
        # counted without a branch: free and unknown voxels alternate unpredictably
        free += wp.where(state == 1, 1, 0)
        unknown += wp.where(state == 1, 0, 1)
        if tx < ty and tx < tz:
            t_entry = tx
            x += sx
            tx += dx
        elif ty < tz:
            t_entry = ty
            y += sy
            ty += dy
        else:
            t_entry = tz
            z += sz
            tz += dz
        steps += 1
    hit[tid] = found
    distance[tid] = wp.float32(t_hit)
    num_unknown[tid] = unknown
    num_free[tid] = free


@wp.kernel
def fill_ray_bases(
    grid: wp.array(dtype=wp.int32),
    grid_dims: wp.vec3i,
    padded_dims: wp.vec3i,
    empty_base: int,
    bases: wp.array(dtype=wp.int32),
):
    """bases[cell] for cast_rays_on_grid: the first states word of the block in each cell of the
    block grid (fill_block_grid) padded by one cell on every side; `empty_base` (a block of
    unknown voxels) in the padding and where no block is."""
    tid = wp.tid()
    z = tid % padded_dims[2] - 1
    y = (tid / padded_dims[2]) % padded_dims[1] - 1
    x = tid / (padded_dims[2] * padded_dims[1]) - 1
    base = empty_base
    if x >= 0 and y >= 0 and z >= 0 and x < grid_dims[0] and y < grid_dims[1] and z < grid_dims[2]:
        slot = grid[(x * grid_dims[1] + y) * grid_dims[2] + z]
        if slot >= 0:
            base = slot * 32
    bases[tid] = base


@wp.kernel
def fill_dense_states(
    log_odds: wp.array(dtype=wp.float32),
    slot_keys: wp.array(dtype=wp.int64),
    log_occupied: wp.float32,
    log_free: wp.float32,
    corner: wp.vec3i,
    dims: wp.vec3i,
    columns: wp.array(dtype=wp.uint16),
):
    """The states (two bits a voxel, 0 unknown, 1 free, 2 occupied) of every voxel of a box, for
    cast_rays_dense: columns[((x dims[1] + y) dims[2] + z) / 8] holds voxels z .. z + 7 of
    column (x, y), counted from the box's `corner` voxel (a multiple of 8), as `columns` was
    zeroed: unknown. One thread per block slot and column of eight voxels."""
    tid = wp.tid()
    slot = tid / 64
    key = slot_keys[slot]
    if key == EMPTY_KEY:
        return
    b = unpack_block(key)
    cx = (tid / 8) % 8
    cy = tid % 8
    bits = wp.uint32(0)
    for z in range(8):
        value = log_odds[slot * BLOCK_VOXELS + (cx << 6) + (cy << 3) + z]
        bits = bits | (voxel_state(value, log_occupied, log_free) << wp.uint32(2 * z))
    x = b[0] * 8 + cx - corner[0]
    y = b[1] * 8 + cy - corner[1]
    columns[((x * dims[1] + y) * dims[2] + b[2] * 8 - corner[2]) / 8] = wp.uint16(bits)


def _cast_rays_for_cpu(dense: bool):
    """cast_rays, bit for bit, for a CPU: a voxel's state is read at every step with no test in
    between (a CPU mispredicts a test at each block crossing, every eight steps or so at random,
    and pays more for it than for a load). The walk counts voxels from the corner of the map's
    box padded by a block each way ((grid_lo - 1) 8, a multiple of 8: a voxel's bits within its
    block stay), and the unknown voxels are the steps less the free ones.

    dense: the state of every voxel of that box (fill_dense_states), the voxel's index moved
    with the walk, one stride a step; a voxel outside the box (three unsigned comparisons, true
    for nearly every step, so well predicted) is unknown. Otherwise, the padded block grid of
    fill_ray_bases and the blocks' states: a block's cell is a shift and an unsigned clamp onto
    the padding (a voxel below the corner wraps past the top), which names a block of unknown
    voxels, so there is no bounds test and no test for a missing block.

    The variant's code alone is generated (wp.static); the other's arrays may be empty.
    """

    @wp.kernel(name="cast_rays_dense" if dense else "cast_rays_on_grid")
    def cast(
        origins: wp.array(dtype=wp.vec3d),
        directions: wp.array(dtype=wp.vec3d),
        max_ranges: wp.array(dtype=wp.float64),
        resolution: wp.float64,
        inv_resolution: wp.float64,
        grid_lo: wp.vec3i,
        known_lo: wp.vec3i,
        known_hi: wp.vec3i,
        count_after: int,
        key_limit: int,
        padded_dims: wp.vec3i,
        columns: wp.array(dtype=wp.uint16),
        bases: wp.array(dtype=wp.int32),
        states: wp.array(dtype=wp.uint32),
        hit: wp.array(dtype=wp.bool),
        distance: wp.array(dtype=wp.float32),
        num_unknown: wp.array(dtype=wp.int32),
        num_free: wp.array(dtype=wp.int32),
    ):
        tid = wp.tid()
        origin, direction = origins[tid], unit_direction(directions[tid])
        max_range = max_ranges[wp.where(max_ranges.shape[0] == 1, 0, tid)]  # one range: for every ray
        s = ray_cast_start(origin, direction, max_range, resolution, inv_resolution, known_lo, known_hi, key_limit)
        voxel, t_max, t_delta, step = s.voxel, s.t_max, s.t_delta, s.step
        ox, oy, oz = (grid_lo[0] - 1) * 8, (grid_lo[1] - 1) * 8, (grid_lo[2] - 1) * 8
        x, y, z = voxel[0] - ox, voxel[1] - oy, voxel[2] - oz  # from the box's corner
        tx, ty, tz = t_max[0], t_max[1], t_max[2]
        dx, dy, dz = t_delta[0], t_delta[1], t_delta[2]
        sx, sy, sz = step[0], step[1], step[2]
        if wp.static(dense):  # voxels per axis; the index in 64 bits: outside the box, where it
            # is not read, it may leave int32's range
            size_x, size_y, size_z = (
                wp.uint32(padded_dims[0] * 8),
                wp.uint32(padded_dims[1] * 8),
                wp.uint32(padded_dims[2] * 8),
            )
            dim_y, dim_z = padded_dims[1] * 8, padded_dims[2] * 8
            stride_x, stride_y, stride_z = wp.int64(sx * dim_y * dim_z), wp.int64(sy * dim_z), wp.int64(sz)
            index = (wp.int64(x) * wp.int64(dim_y) + wp.int64(y)) * wp.int64(dim_z) + wp.int64(z)
        else:  # the padded grid's last cell per axis
            top_x, top_y, top_z = (
                wp.uint32(padded_dims[0] - 1),
                wp.uint32(padded_dims[1] - 1),
                wp.uint32(padded_dims[2] - 1),
            )
            dim_y, dim_z = padded_dims[1], padded_dims[2]
        t_entry, t_end, t_after = wp.float64(s.t_entry), wp.float64(s.t_end), wp.float64(s.t_after)
        max_steps = int(s.max_steps)
        steps = int(s.skipped)
        rest = int(0)  # unknown voxels past the map, counted without walking them
        free = int(0)
        found = bool(False)
        t_hit = max_range
        while t_entry < t_end and steps <= max_steps:
            if t_entry > t_after:  # past the map: count the rest of a long stretch
                t_after = FAR
                here = wp.vec3i(x + ox, y + oy, z + oz)
                n = ray_voxels_until(origin, direction, here, step, resolution, inv_resolution, t_end)
                if n > count_after:
                    rest = n
                    break
            state = int(0)
            if wp.static(dense):
                if (int(wp.uint32(x) < size_x) & int(wp.uint32(y) < size_y) & int(wp.uint32(z) < size_z)) != 0:
                    i = int(index)  # inside the box: below its voxel count
                    bits = wp.uint32(columns[(i >> 3) & 0x7FFFFFFF])  # masked as in packed_state
                    state = int((bits >> wp.uint32((i & 7) << 1)) & wp.uint32(3))
            else:
                cx = int(wp.min(wp.uint32(x >> 3), top_x))
                cy = int(wp.min(wp.uint32(y >> 3), top_y))
                cz = int(wp.min(wp.uint32(z >> 3), top_z))
                base = bases[((cx * dim_y + cy) * dim_z + cz) & 0x7FFFFFFF]  # masked as in packed_state
                state = packed_state(states, base, ((x & 7) << 6) | ((y & 7) << 3) | (z & 7))
            if state == 2:
                found = True
                t_hit = t_entry
                break
            free += wp.where(state == 1, 1, 0)
            if tx < ty and tx < tz:
                t_entry = tx
                x += sx
                tx += dx
                if wp.static(dense):
                    index += stride_x
            elif ty < tz:
                t_entry = ty
                y += sy
                ty += dy
                if wp.static(dense):
                    index += stride_y
            else:
                t_entry = tz
                z += sz
                tz += dz
                if wp.static(dense):
                    index += stride_z
            steps += 1
        hit[tid] = found
        distance[tid] = wp.float32(t_hit)
        num_unknown[tid] = steps - free + rest
        num_free[tid] = free

    return cast


cast_rays_dense = _cast_rays_for_cpu(dense=True)
cast_rays_on_grid = _cast_rays_for_cpu(dense=False)


@wp.func
def segment_walk_of(start: wp.vec3f, end: wp.vec3f, resolution: wp.float64, inv_resolution: wp.float64) -> VoxelWalk:
    # A line query visits the voxels a beam from start to end would: free ones plus the end voxel.
    return walk_of_beam(start, wp.vec4f(end[0], end[1], end[2], 1.0), resolution, inv_resolution)


@wp.kernel
def count_line_voxels(
    starts: wp.array(dtype=wp.vec3f),
    ends: wp.array(dtype=wp.vec3f),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    counts: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    w = segment_walk_of(starts[tid], ends[tid], resolution, inv_resolution)
    n = int(1)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active = bool(w.active)
    while active:
        n += 1
        voxel, t_max, _t, _new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        active = segment_continues(voxel, t_max, w, n - 1)
    counts[tid] = n


@wp.kernel
def fill_line_values(
    starts: wp.array(dtype=wp.vec3f),
    ends: wp.array(dtype=wp.vec3f),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    log_odds: wp.array(dtype=wp.float32),
    values: wp.array2d(dtype=wp.float32),
):
    tid = wp.tid()
    w = segment_walk_of(starts[tid], ends[tid], resolution, inv_resolution)
    n = int(0)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active = bool(w.active)
    while active:
        values[tid, n] = known_or_zero(value_in_slot(find_voxel_slot(table_keys, table_slots, voxel), voxel, log_odds))
        n += 1
        voxel, t_max, _t, _new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        active = segment_continues(voxel, t_max, w, n)
    last = voxel_key(ends[tid], inv_resolution)
    values[tid, n] = known_or_zero(value_in_slot(find_voxel_slot(table_keys, table_slots, last), last, log_odds))


@wp.kernel
def fill_line_voxels(
    starts: wp.array(dtype=wp.vec3f),
    ends: wp.array(dtype=wp.vec3f),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    voxels: wp.array2d(dtype=wp.vec3i),
):
    tid = wp.tid()
    w = segment_walk_of(starts[tid], ends[tid], resolution, inv_resolution)
    n = int(0)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active = bool(w.active)
    while active:
        voxels[tid, n] = voxel
        n += 1
        voxel, t_max, _t, _new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        active = segment_continues(voxel, t_max, w, n)
    voxels[tid, n] = voxel_key(ends[tid], inv_resolution)
