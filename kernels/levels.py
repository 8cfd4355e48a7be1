"""Coarse levels of a block map: OctoMap's inner nodes on 8x8x8 blocks.

Level k has voxels of 2^k level-0 voxels per axis: coarse voxel V holds level-0 keys
[V 2^k, (V + 1) 2^k) (OctoMap's node at depth 16 - k, whose keys are aligned the same way) and
the largest log-odds of its observed children, NaN when none is observed: OctoMap's
`getMaxChildLogOdds` after `updateInnerOccupancy`.

A block's edge is 8 = 2^3 voxels, so the voxels of the three levels above a level-j block
each cover voxels of that block alone: its 512 voxels decide 64 voxels one level up (an octant
of its parent block), 8 two levels up and 1 three levels up, and no other block writes those.
So one thread per block fills all three levels from it in one launch, each coarse value the
maximum over the level below it in OctoMap's child order (`computeChildIdx`: x varies
fastest, then y, then z; the first of equal values kept, so a parent keeps the bits, the sign
of a zero included, of the child OctoMap's `getMaxChildLogOdds` would copy). Levels above
j + 3 are filled the same way from the level-(j + 3) blocks.
"""

import warp as wp

from .hashing import BLOCK_VOXELS, find_slot, index_in_block, observed, pack_block, unpack_block

wp.set_module_options({"enable_backward": False})


@wp.func
def larger_observed(best: wp.float32, value: wp.float32) -> wp.float32:
    """The larger of two log-odds, an unobserved one (NaN) ignored."""
    if observed(value) and (not observed(best) or value > best):
        return value
    return best


# Bits of fill_levels_above_blocks' flags: REGION_OBSERVED when the block holds an observed
# voxel; LEVEL_CHANGED << (i - 1) when a voxel it decides i levels up now holds other bits.
REGION_OBSERVED = wp.constant(1)
LEVEL_CHANGED = wp.constant(2)


@wp.func
def same_value(a: wp.float32, b: wp.float32) -> bool:
    """Whether two log-odds are the same bits: both unobserved (NaN), or equal and, if zero, of
    the same sign (a parent's maximum keeps the sign of the zero it copies)."""
    if not observed(a):
        return not observed(b)
    return a == b and (a != wp.float32(0.0) or wp.sign(wp.float32(1.0) / a) == wp.sign(wp.float32(1.0) / b))


@wp.func
def shifted_block(block: wp.vec3i, levels: int) -> wp.vec3i:
    return wp.vec3i(block[0] >> levels, block[1] >> levels, block[2] >> levels)


@wp.func
def corner_in_parent(block: wp.vec3i, levels: int) -> wp.vec3i:
    """The first voxel, inside its block `levels` levels up, of the voxels a block decides."""
    mask = (1 << levels) - 1
    edge = 8 >> levels
    return wp.vec3i((block[0] & mask) * edge, (block[1] & mask) * edge, (block[2] & mask) * edge)


@wp.func
def octant(corner: wp.vec3i, o: int, size: int) -> wp.vec3i:
    """Child `o` of the cube of edge 2 size at `corner`, numbered as OctoMap numbers a node's
    children: bit 0 x, bit 1 y, bit 2 z."""
    return wp.vec3i(corner[0] + (o & 1) * size, corner[1] + ((o >> 1) & 1) * size, corner[2] + ((o >> 2) & 1) * size)


@wp.func
def cell_bit(voxel: wp.vec3i) -> wp.uint64:
    """The bit, in a block's cell mask, of the 2x2x2 cell holding `voxel` (coordinates in the
    block, 0-7): (x >> 1) * 16 + (y >> 1) * 4 + (z >> 1). Integration sets it
    (`integration.note_changed_cell`), the fill reads it."""
    return wp.uint64(1) << wp.uint64((voxel[0] >> 1) * 16 + (voxel[1] >> 1) * 4 + (voxel[2] >> 1))


@wp.func
def cube_cells(cube: wp.vec3i) -> wp.uint64:
    """The bits of the eight cells of the 4x4x4 cube at voxel `cube` (coordinates 0 or 4)."""
    cells = wp.uint64(0)
    for o in range(8):
        cells = cells | cell_bit(octant(cube, o, 2))
    return cells


@wp.func
def write_value(log_odds: wp.array(dtype=wp.float32), index: int, value: wp.float32) -> int:
    """Store `value`; LEVEL_CHANGED when the voxel held other bits."""
    changed = wp.where(same_value(log_odds[index], value), 0, 1)
    log_odds[index] = value
    return changed


@wp.kernel
def fill_levels_above_blocks(
    keys: wp.array(dtype=wp.int64),
    cells: wp.array(dtype=wp.uint64),
    count: wp.array(dtype=wp.int32),
    depth: int,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    log_odds: wp.array(dtype=wp.float32),
    table_keys_1: wp.array(dtype=wp.int64),
    table_slots_1: wp.array(dtype=wp.int32),
    table_keys_2: wp.array(dtype=wp.int64),
    table_slots_2: wp.array(dtype=wp.int32),
    table_keys_3: wp.array(dtype=wp.int64),
    table_slots_3: wp.array(dtype=wp.int32),
    log_odds_1: wp.array(dtype=wp.float32),
    log_odds_2: wp.array(dtype=wp.float32),
    log_odds_3: wp.array(dtype=wp.float32),
    flags: wp.array(dtype=wp.int32),
):
    """From the blocks with packed keys `keys` (distinct; a key absent from the table: a block of
    unobserved voxels), the voxels they decide in the `depth` (1-3) levels above, whose blocks are
    all in their tables (_1: one level up, ...; a level beyond `depth` is not read or written).
    cells[tid]: the block's 2x2x2 cells whose voxels may have changed (`cell_bit`); the voxels
    above the others hold their values already and are read, not recomputed.
    One thread per block, for the first count[0] keys (a launch recorded once serves any
    number up to its size); flags[tid] as REGION_OBSERVED and LEVEL_CHANGED say, or, when a
    parent block is missing, -1 - m with bit i - 1 of m set where the one i levels up is: nothing
    is written then."""
    tid = wp.tid()
    if tid >= count[0]:
        return
    key = keys[tid]
    block = unpack_block(key)
    slot = find_slot(table_keys, table_slots, key)
    base_1 = find_slot(table_keys_1, table_slots_1, pack_block(shifted_block(block, 1))) * BLOCK_VOXELS
    corner_1 = corner_in_parent(block, 1)
    base_2 = int(0)
    corner_2 = wp.vec3i(0, 0, 0)
    if depth >= 2:
        base_2 = find_slot(table_keys_2, table_slots_2, pack_block(shifted_block(block, 2))) * BLOCK_VOXELS
        corner_2 = corner_in_parent(block, 2)
    base_3 = int(0)
    if depth >= 3:
        base_3 = find_slot(table_keys_3, table_slots_3, pack_block(shifted_block(block, 3))) * BLOCK_VOXELS
    missing = wp.where(base_1 < 0, 1, 0) | wp.where(base_2 < 0, 2, 0) | wp.where(base_3 < 0, 4, 0)
    if missing != 0:  # the host allocates the missing parents and fills the block again
        flags[tid] = -1 - missing
        return
    mask = cells[tid]
    changed_1 = int(0)
    changed_2 = int(0)
    best_3 = wp.float32(wp.nan)
    for o2 in range(8):  # the block's eight cubes of 4^3 voxels: one voxel two levels up each
        cube_2 = octant(wp.vec3i(0, 0, 0), o2, 4)
        up_2 = wp.vec3i(corner_2[0] + cube_2[0] / 4, corner_2[1] + cube_2[1] / 4, corner_2[2] + cube_2[2] / 4)
        best_2 = wp.float32(wp.nan)
        if depth >= 2 and (mask & cube_cells(cube_2)) == wp.uint64(0):  # none of its cells changed
            best_2 = log_odds_2[base_2 + index_in_block(up_2)]
        else:
            for o1 in range(8):  # its cubes of 2^3 voxels: one voxel one level up each
                cube_1 = octant(cube_2, o1, 2)
                up_1 = wp.vec3i(corner_1[0] + cube_1[0] / 2, corner_1[1] + cube_1[1] / 2, corner_1[2] + cube_1[2] / 2)
                best_1 = wp.float32(wp.nan)
                if (mask & cell_bit(cube_1)) == wp.uint64(0):
                    best_1 = log_odds_1[base_1 + index_in_block(up_1)]
                else:
                    if slot >= 0:
                        for o0 in range(8):
                            voxel = octant(cube_1, o0, 1)
                            best_1 = larger_observed(best_1, log_odds[slot * BLOCK_VOXELS + index_in_block(voxel)])
                    changed_1 = changed_1 | write_value(log_odds_1, base_1 + index_in_block(up_1), best_1)
                best_2 = larger_observed(best_2, best_1)
            if depth >= 2:
                changed_2 = changed_2 | write_value(log_odds_2, base_2 + index_in_block(up_2), best_2)
        best_3 = larger_observed(best_3, best_2)
    changed_3 = int(0)
    if depth >= 3:
        changed_3 = write_value(log_odds_3, base_3 + index_in_block(block), best_3)
    seen = wp.where(observed(best_3), REGION_OBSERVED, 0)
    flags[tid] = seen | (changed_1 * LEVEL_CHANGED) | (changed_2 * LEVEL_CHANGED * 2) | (changed_3 * LEVEL_CHANGED * 4)


@wp.kernel
def find_observed_blocks(
    keys: wp.array(dtype=wp.int64),
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    log_odds: wp.array(dtype=wp.float32),
    holds_observed: wp.array(dtype=wp.int32),
):
    """Whether the block with packed key keys[tid] (in the table) holds an observed voxel."""
    tid = wp.tid()
    base = find_slot(table_keys, table_slots, keys[tid]) * BLOCK_VOXELS
    seen = int(0)
    for i in range(BLOCK_VOXELS):
        if observed(log_odds[base + i]):
            seen = 1
    holds_observed[tid] = seen
