"""Coarse levels of a block map: OctoMap's inner nodes on 8x8x8 blocks.

Level k has voxels of 2^k level-0 voxels per axis: coarse voxel V holds level-0 keys
[V 2^k, (V + 1) 2^k) (OctoMap's node at depth 16 - k, whose keys are aligned the same way) and
the largest log-odds of its observed children, NaN when none is observed: OctoMap's
`getMaxChildLogOdds` after `updateInnerOccupancy`. Each level is built from the one below:
the maximum over the children's maxima is the maximum over all their voxels.

A coarse block (8^3 voxels of level k) covers 2 x 2 x 2 blocks of level k - 1: its octant o
holds the coarse voxels whose children fill child block 2 B + o, so one thread per (block,
octant) finds that child block once and writes its 64 coarse voxels. It also says whether any
of them changed, bit for bit: a coarse block whose voxels all stayed gives its parent nothing new,
so the level above need not recompute it (nor the levels above that, when none changed).
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


# Bits of fill_coarse_blocks' octant_flags.
OCTANT_OBSERVED = wp.constant(1)  # the octant holds an observed voxel
OCTANT_CHANGED = wp.constant(2)  # a voxel of the octant now holds other bits than before


@wp.func
def same_value(a: wp.float32, b: wp.float32) -> bool:
    """Whether two log-odds are the same bits: both unobserved (NaN), or equal and, if zero, of
    the same sign (a parent's maximum keeps the sign of the zero it copies)."""
    if not observed(a):
        return not observed(b)
    return a == b and (a != wp.float32(0.0) or wp.sign(wp.float32(1.0) / a) == wp.sign(wp.float32(1.0) / b))


@wp.kernel
def fill_coarse_blocks(
    keys: wp.array(dtype=wp.int64),
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    child_table_keys: wp.array(dtype=wp.int64),
    child_table_slots: wp.array(dtype=wp.int32),
    child_log_odds: wp.array(dtype=wp.float32),
    log_odds: wp.array(dtype=wp.float32),
    octant_flags: wp.array(dtype=wp.int32),
):
    """Recompute every voxel of the coarse blocks with packed keys `keys` (all in the coarse
    store's table) from the level below (child_*). One thread per (block, octant): tid = 8 b + o;
    octant_flags[tid] has OCTANT_OBSERVED when the octant holds an observed voxel (none in all
    eight: the block is empty) and OCTANT_CHANGED when one of its voxels changed."""
    tid = wp.tid()
    key = keys[tid / 8]
    slot = find_slot(table_keys, table_slots, key)
    octant = tid % 8
    ox = (octant >> 2) & 1
    oy = (octant >> 1) & 1
    oz = octant & 1
    block = unpack_block(key)
    child_block = wp.vec3i(2 * block[0] + ox, 2 * block[1] + oy, 2 * block[2] + oz)
    child_slot = find_slot(child_table_keys, child_table_slots, pack_block(child_block))
    base = slot * BLOCK_VOXELS
    child_base = child_slot * BLOCK_VOXELS
    seen = int(0)
    changed = int(0)
    for lx in range(4):
        for ly in range(4):
            for lz in range(4):
                best = wp.float32(wp.nan)
                if child_slot >= 0:
                    for c in range(8):
                        child = wp.vec3i(2 * lx + ((c >> 2) & 1), 2 * ly + ((c >> 1) & 1), 2 * lz + (c & 1))
                        best = larger_observed(best, child_log_odds[child_base + index_in_block(child)])
                index = base + index_in_block(wp.vec3i(4 * ox + lx, 4 * oy + ly, 4 * oz + lz))
                if not same_value(log_odds[index], best):
                    changed = OCTANT_CHANGED
                log_odds[index] = best
                if observed(best):
                    seen = OCTANT_OBSERVED
    octant_flags[tid] = seen | changed
