"""Transform-and-accumulate: adding (or removing) a submap's contribution to the global map.

Contribution rule ("pull"): global voxel x receives the value of the submap voxel that contains
T^-1 x (x's centre taken to the submap frame), if that voxel was observed. Every global voxel
then gets at most one value per submap, whatever the rotation: no holes, no double hits.

Work is enumerated per submap block: the global voxel centres inside the block's transformed
box are found column by column (x, y) with a z range from the box's slabs, widened by a voxel
and then filtered exactly, so each global voxel is visited by the one block it pulls from. One
launch covers the blocks of many submaps (a `SubmapView` each, rows = (submap, block)); sums are
integer atomics, so their order never matters. On the CPU a launch is split across threads
only within one submap, where no two threads write the same global voxel (CPU atomics are not
atomic across threads).

Sums are fixed point: an integer number of 2^-24 log-odds steps, so removing a submap restores
the exact bits a map without it would hold.
"""

import warp as wp

from .fixed_point import from_fixed_point, to_fixed_point
from .hashing import BLOCK_VOXELS, EMPTY_KEY, block_of, find_slot, index_in_block, pack_block, unpack_block
from .submap_view import SubmapView, pull_voxel, voxel_centre
from .traversal import same_voxel

wp.set_module_options({"enable_backward": False})

# Global voxel centres near a rotated 8-voxel block: at most 14 indices per axis, plus margins.
COLUMN_SPAN = 18
# ... which meet at most 4 global blocks per axis.
BLOCKS_PER_BOX = 64
SPAN = wp.constant(COLUMN_SPAN)
FAR = wp.constant(wp.float64(1.0e300))


@wp.func
def block_box(block: wp.vec3i, rotation: wp.mat33d, translation: wp.vec3d, resolution: wp.float64):
    """First and last global voxel index per axis whose centre may lie in the block's
    transformed box, with a voxel of margin against round-off."""
    half_edge = wp.float64(4.0) * resolution
    centre = rotation * (wp.vec3d(wp.float64(block[0] * 8 + 4), wp.float64(block[1] * 8 + 4),
                                  wp.float64(block[2] * 8 + 4)) * resolution) + translation
    half = wp.float64(0.5)
    first = wp.vec3i(0, 0, 0)
    last = wp.vec3i(0, 0, 0)
    for axis in range(3):
        extent = (wp.abs(rotation[axis, 0]) + wp.abs(rotation[axis, 1]) + wp.abs(rotation[axis, 2])) * half_edge
        # centre (k + 0.5) s in [lo, hi]  <=>  lo / s - 0.5 <= k <= hi / s - 0.5
        first[axis] = int(wp.floor((centre[axis] - extent) / resolution - half)) - 1
        last[axis] = wp.min(int(wp.floor((centre[axis] + extent) / resolution - half)) + 1,
                            first[axis] + SPAN - 1)
    return first, last


@wp.func
def column_range(i: int, j: int, start_k: int, block: wp.vec3i, rotation_t: wp.mat33d,
                 translation: wp.vec3d, resolution: wp.float64) -> wp.vec2i:
    """Global z indices of column (i, j) whose centres lie in the block's box.

    The box is widened by a millionth of a voxel against round-off; `pulled_value` decides
    exactly, so a superset here is harmless and a tight one saves the work.
    """
    half = wp.float64(0.5)
    base = rotation_t * (wp.vec3d((wp.float64(i) + half) * resolution,
                                  (wp.float64(j) + half) * resolution, wp.float64(0.0)) - translation)
    along = wp.vec3d(rotation_t[0, 2], rotation_t[1, 2], rotation_t[2, 2])  # d(local)/d(world z)
    margin = wp.float64(1e-6) * resolution
    z_lo = -FAR
    z_hi = FAR
    for axis in range(3):
        lo = wp.float64(block[axis] * 8) * resolution - margin
        hi = wp.float64(block[axis] * 8 + 8) * resolution + margin
        if wp.abs(along[axis]) < wp.float64(1e-12):
            if base[axis] < lo or base[axis] > hi:
                return wp.vec2i(0, -1)
        else:
            a = (lo - base[axis]) / along[axis]
            b = (hi - base[axis]) / along[axis]
            z_lo = wp.max(z_lo, wp.min(a, b))
            z_hi = wp.min(z_hi, wp.max(a, b))
    if z_lo > z_hi:
        return wp.vec2i(0, -1)
    # centre (k + 0.5) s in [z_lo, z_hi]
    first = wp.max(int(wp.ceil(z_lo / resolution - half)), start_k)
    last = wp.min(int(wp.floor(z_hi / resolution - half)), start_k + SPAN - 1)
    return wp.vec2i(first, last)


@wp.func
def pulled_value(g: wp.vec3i, block: wp.vec3i, slot: int, rotation_t: wp.mat33d,
                 translation: wp.vec3d, resolution: wp.float64, inv_resolution: wp.float64,
                 local_log_odds: wp.array(dtype=wp.float32)) -> wp.float32:
    """Value global voxel g pulls from submap block `block` (NaN: not from it, or unobserved)."""
    local = pull_voxel(voxel_centre(g, resolution), rotation_t, translation, inv_resolution)
    if not same_voxel(block_of(local), block):
        return wp.nan
    return local_log_odds[slot * BLOCK_VOXELS + index_in_block(local)]


# The two kernels below open with the same dozen lines; a shared func returning the column
# measured 10-20% slower on the CPU, so they stay written out.


@wp.kernel
def collect_pull_blocks(sources: wp.array(dtype=SubmapView), row_source: wp.array(dtype=wp.int32),
                        row_slot: wp.array(dtype=wp.int32), first_row: int, resolution: wp.float64,
                        inv_resolution: wp.float64, global_keys: wp.array2d(dtype=wp.int64)):
    """global_keys[row, :] = the global blocks a row's submap block contributes to (EMPTY elsewhere)."""
    b, u, v = wp.tid()
    row = first_row + b
    source = sources[row_source[row]]
    slot = row_slot[row]
    local_slot_keys = wp.array(ptr=source.slot_keys, shape=(source.block_capacity,), dtype=wp.int64)
    key = local_slot_keys[slot]
    if key == EMPTY_KEY:
        return
    local_log_odds = wp.array(ptr=source.log_odds, shape=(source.block_capacity * BLOCK_VOXELS,), dtype=wp.float32)
    rotation, rotation_t, translation = source.rotation, source.rotation_t, source.translation
    block = unpack_block(key)
    start, last = block_box(block, rotation, translation, resolution)
    i = start[0] + u
    j = start[1] + v
    if i > last[0] or j > last[1]:
        return
    ks = column_range(i, j, start[2], block, rotation_t, translation, resolution)
    first_block = block_of(start)
    for k in range(ks[0], ks[1] + 1):
        g = wp.vec3i(i, j, k)
        if not wp.isnan(pulled_value(g, block, slot, rotation_t, translation, resolution,
                                     inv_resolution, local_log_odds)):
            gb = block_of(g)
            offset = ((gb[0] - first_block[0]) * 4 + (gb[1] - first_block[1])) * 4 + gb[2] - first_block[2]
            global_keys[row, offset] = pack_block(gb)


@wp.kernel
def accumulate_pulls(sources: wp.array(dtype=SubmapView), row_source: wp.array(dtype=wp.int32),
                     row_slot: wp.array(dtype=wp.int32), first_row: int, resolution: wp.float64,
                     inv_resolution: wp.float64, sign: int, table_keys: wp.array(dtype=wp.int64),
                     table_slots: wp.array(dtype=wp.int32), part: int,
                     sums: wp.array(dtype=wp.int64), counts: wp.array(dtype=wp.int32),
                     pulls: wp.array(dtype=wp.int32)):
    """Add (sign +1) or remove (sign -1) a row's submap block values at every voxel pulling them."""
    b, u, v = wp.tid()
    row = first_row + b
    source = sources[row_source[row]]
    slot = row_slot[row]
    local_slot_keys = wp.array(ptr=source.slot_keys, shape=(source.block_capacity,), dtype=wp.int64)
    key = local_slot_keys[slot]
    if key == EMPTY_KEY:
        return
    local_log_odds = wp.array(ptr=source.log_odds, shape=(source.block_capacity * BLOCK_VOXELS,), dtype=wp.float32)
    rotation, rotation_t, translation = source.rotation, source.rotation_t, source.translation
    block = unpack_block(key)
    start, last = block_box(block, rotation, translation, resolution)
    i = start[0] + u
    j = start[1] + v
    if i > last[0] or j > last[1]:
        return
    ks = column_range(i, j, start[2], block, rotation_t, translation, resolution)
    global_slot = int(-1)
    current = wp.vec3i(0, 0, 0)
    n = int(0)
    for k in range(ks[0], ks[1] + 1):
        g = wp.vec3i(i, j, k)
        value = pulled_value(g, block, slot, rotation_t, translation, resolution, inv_resolution,
                             local_log_odds)
        if not wp.isnan(value):
            gb = block_of(g)
            if global_slot < 0 or not same_voxel(gb, current):
                global_slot = find_slot(table_keys, table_slots, pack_block(gb))
                current = gb
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
def refresh_log_odds(slots: wp.array(dtype=wp.int32), sums: wp.array(dtype=wp.int64),
                     counts: wp.array(dtype=wp.int32), clamp_min: wp.float32, clamp_max: wp.float32,
                     log_odds: wp.array(dtype=wp.float32)):
    """The queryable log-odds layer of the given global blocks, from their sums and counts."""
    tid = wp.tid()
    index = slots[tid // BLOCK_VOXELS] * BLOCK_VOXELS + tid % BLOCK_VOXELS
    log_odds[index] = from_fixed_point(sums[index], counts[index], clamp_min, clamp_max)


@wp.kernel
def flag_unused_blocks(slots: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
                       unused: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    base = slots[tid] * BLOCK_VOXELS
    flag = int(1)
    for i in range(BLOCK_VOXELS):
        if counts[base + i] != 0:
            flag = 0
            break
    unused[tid] = flag
