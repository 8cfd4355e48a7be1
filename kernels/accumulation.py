"""Transform-and-accumulate: adding (or removing) a submap's contribution to the global map.

Contribution rule ("pull"): global voxel x receives the value of the submap voxel that contains
T^-1 x (x's centre taken to the submap frame), if that voxel was observed. Every global voxel
then gets at most one value per submap, whatever the rotation: no holes, no double hits.

Work is enumerated per submap block: the global voxel centres inside the block's transformed
box are found column by column (x, y) with a z range from the box's slabs, widened by a voxel
and then filtered exactly, so each global voxel is visited by the one block it pulls from. One
launch covers the blocks of many submaps (a `SubmapView` each, rows = (submap, block)); sums are
integer atomics, so their order never matters. On the CPU, where atomics are not atomic across
threads, a launch is split across threads by rows that write to disjoint global blocks.

Sums are fixed point: an integer number of 2^-24 log-odds steps, so removing a submap restores
the exact bits a map without it would hold.
"""

import warp as wp

from .fixed_point import from_fixed_point, to_fixed_point
from .hashing import BLOCK_VOXELS, EMPTY_KEY, block_of, index_in_block, observed, pack_block, unpack_block
from .submap_view import SubmapView, pull_voxel, voxel_centre
from .traversal import same_voxel

wp.set_module_options({"enable_backward": False})

# Global voxel centres near a rotated 8-voxel block: at most 14 indices per axis, plus margins.
COLUMN_SPAN = 18
# ... which meet at most 4 global blocks per axis.
BLOCKS_PER_BOX = 64
BLOCKS_PER_BOX_C = wp.constant(BLOCKS_PER_BOX)
SPAN = wp.constant(COLUMN_SPAN)
FAR = wp.constant(wp.float64(1.0e300))


@wp.func
def block_box(block: wp.vec3i, rotation: wp.mat33d, translation: wp.vec3d, resolution: wp.float64):
    """First and last global voxel index per axis whose centre may lie in the block's
    transformed box, with a voxel of margin against round-off."""
    half_edge = wp.float64(4.0) * resolution
    centre = (
        rotation
        * (
            wp.vec3d(wp.float64(block[0] * 8 + 4), wp.float64(block[1] * 8 + 4), wp.float64(block[2] * 8 + 4))
            * resolution
        )
        + translation
    )
    half = wp.float64(0.5)
    first = wp.vec3i(0, 0, 0)
    last = wp.vec3i(0, 0, 0)
    for axis in range(3):
        extent = (wp.abs(rotation[axis, 0]) + wp.abs(rotation[axis, 1]) + wp.abs(rotation[axis, 2])) * half_edge
        # centre (k + 0.5) s in [lo, hi]  <=>  lo / s - 0.5 <= k <= hi / s - 0.5
        first[axis] = int(wp.floor((centre[axis] - extent) / resolution - half)) - 1
        last[axis] = wp.min(int(wp.floor((centre[axis] + extent) / resolution - half)) + 1, first[axis] + SPAN - 1)
    return first, last


@wp.struct
class Columns:
    """What a thread needs to find, column after column (global j at fixed i), the global z
    indices whose centres may lie in a submap block's box: the box in the submap frame (widened
    by a millionth of a voxel against round-off), the submap-frame point of the current column
    at world z = 0 and its step per column, and 1 / d(local)/d(world z) per axis (0: parallel)."""

    lo: wp.vec3d
    hi: wp.vec3d
    base: wp.vec3d
    step: wp.vec3d
    inv_along: wp.vec3d


@wp.func
def columns_at(
    i: int, j: int, block: wp.vec3i, rotation_t: wp.mat33d, translation: wp.vec3d, resolution: wp.float64
) -> Columns:
    c = Columns()
    half = wp.float64(0.5)
    margin = wp.float64(1e-6) * resolution
    c.base = rotation_t * (
        wp.vec3d((wp.float64(i) + half) * resolution, (wp.float64(j) + half) * resolution, wp.float64(0.0))
        - translation
    )
    c.step = wp.vec3d(rotation_t[0, 1], rotation_t[1, 1], rotation_t[2, 1]) * resolution
    for axis in range(3):
        c.lo[axis] = wp.float64(block[axis] * 8) * resolution - margin
        c.hi[axis] = wp.float64(block[axis] * 8 + 8) * resolution + margin
        along = rotation_t[axis, 2]
        c.inv_along[axis] = wp.where(wp.abs(along) < wp.float64(1e-12), wp.float64(0.0), wp.float64(1.0) / along)
    return c


@wp.func
def column_range(base: wp.vec3d, c: Columns, start_k: int, inv_resolution: wp.float64) -> wp.vec2i:
    """Global z indices of the column at `base` whose centres lie in the block's box.

    A superset is harmless (`pulled_value` decides exactly; the base advances by sums and the
    bounds use reciprocals, rounding far inside the margin), and a tight one saves the work.
    """
    z_lo = -FAR
    z_hi = FAR
    for axis in range(3):
        if c.inv_along[axis] == wp.float64(0.0):
            if base[axis] < c.lo[axis] or base[axis] > c.hi[axis]:
                return wp.vec2i(0, -1)
        else:
            a = (c.lo[axis] - base[axis]) * c.inv_along[axis]
            b = (c.hi[axis] - base[axis]) * c.inv_along[axis]
            z_lo = wp.max(z_lo, wp.min(a, b))
            z_hi = wp.min(z_hi, wp.max(a, b))
    if z_lo > z_hi:
        return wp.vec2i(0, -1)
    # centre (k + 0.5) s in [z_lo, z_hi]
    half = wp.float64(0.5)
    first = wp.max(int(wp.ceil(z_lo * inv_resolution - half)), start_k)
    last = wp.min(int(wp.floor(z_hi * inv_resolution - half)), start_k + SPAN - 1)
    return wp.vec2i(first, last)


@wp.func
def box_offset(g: wp.vec3i, first_block: wp.vec3i) -> int:
    """Index of g's global block among the 4x4x4 blocks from first_block (a row's box)."""
    gb = block_of(g)
    return ((gb[0] - first_block[0]) * 4 + (gb[1] - first_block[1])) * 4 + gb[2] - first_block[2]


@wp.func
def pulled_value(
    g: wp.vec3i,
    block: wp.vec3i,
    slot: int,
    rotation_t: wp.mat33d,
    translation: wp.vec3d,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    local_log_odds: wp.array(dtype=wp.float32),
) -> wp.float32:
    """Value global voxel g pulls from submap block `block` (NaN: not from it, or unobserved)."""
    local = pull_voxel(voxel_centre(g, resolution), rotation_t, translation, inv_resolution)
    if not same_voxel(block_of(local), block):
        return wp.nan
    return local_log_odds[slot * BLOCK_VOXELS + index_in_block(local)]


@wp.func
def row_block(
    sources: wp.array(dtype=SubmapView),
    row_source: wp.array(dtype=wp.int32),
    row_slot: wp.array(dtype=wp.int32),
    row: int,
) -> wp.vec3i:
    """The submap block of a row (its slot's key unpacked); x = -2^30 for a released slot."""
    source_index = row_source[row]
    local_slot_keys = wp.array(
        ptr=sources[source_index].slot_keys, shape=(sources[source_index].block_capacity,), dtype=wp.int64
    )
    key = local_slot_keys[row_slot[row]]
    if key == EMPTY_KEY:
        return wp.vec3i(-(1 << 30), 0, 0)
    return unpack_block(key)


# The two kernels below share their opening; a thread takes one row (a submap block) and one
# global x index of its box, and walks the box's columns (y) and their z ranges itself: the
# row's set-up (view, box) is paid once per x instead of once per column.


@wp.kernel
def collect_pull_blocks(
    sources: wp.array(dtype=SubmapView),
    row_source: wp.array(dtype=wp.int32),
    row_slot: wp.array(dtype=wp.int32),
    first_row: int,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    row_masks: wp.array(dtype=wp.uint64),
):
    """row_masks[row] |= the global blocks a row's submap block contributes to: bit `offset`
    (box_offset) of each among the 4x4x4 blocks of the row's box."""
    b, u = wp.tid()
    row = first_row + b
    block = row_block(sources, row_source, row_slot, row)
    if block[0] == -(1 << 30):
        return
    source = sources[row_source[row]]
    rotation_t, translation = source.rotation_t, source.translation
    local_log_odds = wp.array(ptr=source.log_odds, shape=(source.block_capacity * BLOCK_VOXELS,), dtype=wp.float32)
    slot = row_slot[row]
    start, last = block_box(block, source.rotation, translation, resolution)
    i = start[0] + u
    if i > last[0]:
        return
    first_block = block_of(start)
    written = wp.uint64(0)  # the global blocks (bits: offsets) this thread found already
    columns = columns_at(i, start[1], block, rotation_t, translation, resolution)
    base = columns.base
    for j in range(start[1], last[1] + 1):
        ks = column_range(base, columns, start[2], inv_resolution)
        base = base + columns.step
        for k in range(ks[0], ks[1] + 1):
            g = wp.vec3i(i, j, k)
            offset = box_offset(g, first_block)
            bit = wp.uint64(1) << wp.uint64(offset)
            if (written & bit) == wp.uint64(0):
                if observed(
                    pulled_value(g, block, slot, rotation_t, translation, resolution, inv_resolution, local_log_odds)
                ):
                    written = written | bit
    if written != wp.uint64(0):
        wp.atomic_or(row_masks, row, written)


@wp.kernel
def row_spans(
    sources: wp.array(dtype=SubmapView),
    row_source: wp.array(dtype=wp.int32),
    row_slot: wp.array(dtype=wp.int32),
    resolution: wp.float64,
    spans: wp.array(dtype=wp.vec4i),
):
    """The global blocks a row may write to, as x and y block ranges (lowest, highest)."""
    row = wp.tid()
    block = row_block(sources, row_source, row_slot, row)
    if block[0] == -(1 << 30):
        spans[row] = wp.vec4i(0, 0, 0, 0)
        return
    source = sources[row_source[row]]
    start, last = block_box(block, source.rotation, source.translation, resolution)
    spans[row] = wp.vec4i(start[0] >> 3, last[0] >> 3, start[1] >> 3, last[1] >> 3)


@wp.kernel
def list_pull_blocks(
    sources: wp.array(dtype=SubmapView),
    row_source: wp.array(dtype=wp.int32),
    row_slot: wp.array(dtype=wp.int32),
    resolution: wp.float64,
    row_masks: wp.array(dtype=wp.uint64),
    row_start: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int64),
):
    """The packed keys of every row's global blocks, row after row, by offset within a row: the
    block of bit b of row r is keys[row_start[r] + (set bits of row_masks[r] below b)]."""
    row = wp.tid()
    mask = row_masks[row]
    if mask == wp.uint64(0):
        return
    block = row_block(sources, row_source, row_slot, row)
    source = sources[row_source[row]]
    start, _last = block_box(block, source.rotation, source.translation, resolution)
    first_block = block_of(start)
    n = row_start[row]
    for offset in range(BLOCKS_PER_BOX_C):
        if (mask >> wp.uint64(offset)) & wp.uint64(1) != wp.uint64(0):
            keys[n] = pack_block(first_block + wp.vec3i(offset >> 4, (offset >> 2) & 3, offset & 3))
            n += 1


@wp.kernel
def accumulate_pulls(
    sources: wp.array(dtype=SubmapView),
    row_source: wp.array(dtype=wp.int32),
    row_slot: wp.array(dtype=wp.int32),
    first_row: int,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    sign: int,
    row_masks: wp.array(dtype=wp.uint64),
    row_start: wp.array(dtype=wp.int32),
    global_slots: wp.array(dtype=wp.int32),
    part: int,
    sums: wp.array(dtype=wp.int64),
    counts: wp.array(dtype=wp.int32),
    pulls: wp.array(dtype=wp.int32),
):
    """Add (sign +1) or remove (sign -1) a row's submap block values at every voxel pulling them.
    global_slots: the map slot of each key of list_pull_blocks."""
    b, u = wp.tid()
    row = first_row + b
    block = row_block(sources, row_source, row_slot, row)
    if block[0] == -(1 << 30):
        return
    source = sources[row_source[row]]
    rotation_t, translation = source.rotation_t, source.translation
    local_log_odds = wp.array(ptr=source.log_odds, shape=(source.block_capacity * BLOCK_VOXELS,), dtype=wp.float32)
    slot = row_slot[row]
    start, last = block_box(block, source.rotation, translation, resolution)
    i = start[0] + u
    if i > last[0]:
        return
    first_block = block_of(start)
    mask = row_masks[row]
    first_key = row_start[row]
    n = int(0)
    columns = columns_at(i, start[1], block, rotation_t, translation, resolution)
    base = columns.base
    for j in range(start[1], last[1] + 1):
        ks = column_range(base, columns, start[2], inv_resolution)
        base = base + columns.step
        for k in range(ks[0], ks[1] + 1):
            g = wp.vec3i(i, j, k)
            value = pulled_value(g, block, slot, rotation_t, translation, resolution, inv_resolution, local_log_odds)
            if observed(value):
                below = mask & ((wp.uint64(1) << wp.uint64(box_offset(g, first_block))) - wp.uint64(1))
                global_slot = global_slots[first_key + wp.bit_count(below)]
                if global_slot >= 0:  # always: the block was listed, and created or found
                    index = global_slot * BLOCK_VOXELS + index_in_block(g)
                    wp.atomic_add(sums, index, wp.int64(sign) * to_fixed_point(value))
                    wp.atomic_add(counts, index, sign)
                    n += 1
    if n > 0:
        wp.atomic_add(pulls, part, n)


@wp.kernel
def flag_slots(slots: wp.array(dtype=wp.int32), flags: wp.array(dtype=wp.int32)):
    """flags[s] = 1 for every slot s >= 0 in `slots`."""
    tid = wp.tid()
    slot = slots[tid]
    if slot >= 0:
        flags[slot] = 1


@wp.kernel
def refresh_log_odds(
    slots: wp.array(dtype=wp.int32),
    sums: wp.array(dtype=wp.int64),
    counts: wp.array(dtype=wp.int32),
    clamp_min: wp.float32,
    clamp_max: wp.float32,
    log_odds: wp.array(dtype=wp.float32),
):
    """The queryable log-odds layer of the given global blocks, from their sums and counts."""
    tid = wp.tid()
    index = slots[tid // BLOCK_VOXELS] * BLOCK_VOXELS + tid % BLOCK_VOXELS
    log_odds[index] = from_fixed_point(sums[index], counts[index], clamp_min, clamp_max)


@wp.kernel
def flag_unused_blocks(
    slots: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), unused: wp.array(dtype=wp.int32)
):
    tid = wp.tid()
    base = slots[tid] * BLOCK_VOXELS
    flag = int(1)
    for i in range(BLOCK_VOXELS):
        if counts[base + i] != 0:
            flag = 0
            break
    unused[tid] = flag
