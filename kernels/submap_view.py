"""A submap placed in the world, as every kernel reads it: one `SubmapView` per submap and pose.

The global map pulls from a view's block pool (accumulation.py), the virtual map looks voxels up
through its hash table (virtual.py); both take the submap voxel containing a world point
(`pull_voxel`), so at voxel centres they agree bit for bit.
"""

import warp as wp

from .hashing import BLOCK_VOXELS, block_of, find_slot, index_in_block, pack_block, voxel_key_in_range

wp.set_module_options({"enable_backward": False})


@wp.struct
class SubmapView:
    table_keys: wp.uint64  # pointer to int64[table_capacity]
    table_slots: wp.uint64  # pointer to int32[table_capacity]
    table_capacity: int
    slot_keys: wp.uint64  # pointer to int64[block_capacity]: each slot's packed block key
    log_odds: wp.uint64  # pointer to float32[block_capacity * BLOCK_VOXELS]
    block_capacity: int
    rotation: wp.mat33d  # R of T_world_submap
    rotation_t: wp.mat33d  # R^T
    translation: wp.vec3d  # t of T_world_submap
    box_lo: wp.vec3d  # submap-frame box of the observed voxels, widened by one voxel
    box_hi: wp.vec3d


@wp.func
def pull_voxel(centre: wp.vec3d, rotation_t: wp.mat33d, translation: wp.vec3d, inv_resolution: wp.float64) -> wp.vec3i:
    """The submap voxel containing a world point: floor(R^T (x - t) / s)."""
    local = rotation_t * (centre - translation)
    return wp.vec3i(
        int(wp.floor(local[0] * inv_resolution)),
        int(wp.floor(local[1] * inv_resolution)),
        int(wp.floor(local[2] * inv_resolution)),
    )


@wp.func
def voxel_centre(voxel: wp.vec3i, resolution: wp.float64) -> wp.vec3d:
    half = wp.float64(0.5)
    return wp.vec3d(
        (wp.float64(voxel[0]) + half) * resolution,
        (wp.float64(voxel[1]) + half) * resolution,
        (wp.float64(voxel[2]) + half) * resolution,
    )


@wp.func
def submap_value(view: SubmapView, world: wp.vec3d, inv_resolution: wp.float64) -> wp.float32:
    """Log-odds of the submap voxel holding a world point; NaN if outside its box or unobserved."""
    local = view.rotation_t * (world - view.translation)
    for axis in range(3):
        if local[axis] < view.box_lo[axis] or local[axis] > view.box_hi[axis]:
            return wp.nan
    voxel = pull_voxel(world, view.rotation_t, view.translation, inv_resolution)
    if not voxel_key_in_range(voxel):
        return wp.nan
    keys = wp.array(ptr=view.table_keys, shape=(view.table_capacity,), dtype=wp.int64)
    slots = wp.array(ptr=view.table_slots, shape=(view.table_capacity,), dtype=wp.int32)
    slot = find_slot(keys, slots, pack_block(block_of(voxel)))
    if slot < 0:
        return wp.nan
    pool = wp.array(ptr=view.log_odds, shape=(view.block_capacity * BLOCK_VOXELS,), dtype=wp.float32)
    return pool[slot * BLOCK_VOXELS + index_in_block(voxel)]
