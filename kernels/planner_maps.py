"""How the planner's kernels read a map: one `MapAccess` for every map kind.

A map is a block store (a VoxelMap's log-odds, or a GlobalMap's fixed-point sums and counts)
plus submaps at poses (`SubmapView`s: every submap of a virtual map, or the submap still being
filled on top of a global map). A voxel's value is the block store's, summed with the submaps'
pulled values the way the global map sums them, so at voxel centres the planner reads what
the map's own queries answer.
"""

import warp as wp

from .fixed_point import from_fixed_point, to_fixed_point
from .hashing import BLOCK_VOXELS, find_voxel_slot, index_in_block, observed
from .submap_view import SubmapView, submap_value, voxel_centre

wp.set_module_options({"enable_backward": False})

# MapAccess.kind
NO_STORE = wp.constant(0)  # submaps only (a virtual map)
LOG_ODDS_STORE = wp.constant(1)  # a VoxelMap's or GlobalMap's float log-odds layer (NaN: unknown)
SUM_STORE = wp.constant(2)  # a GlobalMap's fixed-point sums and counts (summed with submaps)

# voxel states, as vogjax.maps
UNKNOWN = wp.constant(0)
FREE = wp.constant(1)
OCCUPIED = wp.constant(2)


@wp.struct
class MapAccess:
    kind: int
    table_keys: wp.array(dtype=wp.int64)
    table_slots: wp.array(dtype=wp.int32)
    log_odds: wp.array(dtype=wp.float32)
    sums: wp.array(dtype=wp.int64)
    counts: wp.array(dtype=wp.int32)
    views: wp.array(dtype=SubmapView)
    resolution: wp.float64
    inv_resolution: wp.float64
    clamp_min: wp.float32
    clamp_max: wp.float32
    log_occupied: wp.float32
    log_free: wp.float32


@wp.func
def store_slot(m: MapAccess, voxel: wp.vec3i) -> int:
    if m.kind == NO_STORE:
        return -1
    return find_voxel_slot(m.table_keys, m.table_slots, voxel)


@wp.func
def voxel_value(
    m: MapAccess, voxel: wp.vec3i, slot: int, candidates: wp.array(dtype=wp.int32), first: int, last: int
) -> wp.float32:
    """Log-odds of `voxel` (NaN: unobserved); `slot`: its block's slot in the store (-1: none);
    candidates[first:last]: the views that may hold it."""
    if m.kind == LOG_ODDS_STORE:
        if slot < 0:
            return wp.nan
        return m.log_odds[slot * BLOCK_VOXELS + index_in_block(voxel)]
    total = wp.int64(0)
    count = wp.int32(0)
    if m.kind == SUM_STORE and slot >= 0:
        index = slot * BLOCK_VOXELS + index_in_block(voxel)
        total = m.sums[index]
        count = m.counts[index]
    if last > first:
        centre = voxel_centre(voxel, m.resolution)
        for k in range(first, last):
            value = submap_value(m.views[candidates[k]], centre, m.inv_resolution)
            if observed(value):
                total += to_fixed_point(value)
                count += 1
    return from_fixed_point(total, count, m.clamp_min, m.clamp_max)


@wp.func
def state_of(m: MapAccess, value: wp.float32) -> int:
    # NaN fails both comparisons: unknown.
    if value >= m.log_occupied:
        return OCCUPIED
    if value <= m.log_free:
        return FREE
    return UNKNOWN
