"""View gain: the voxels a range sensor would see from candidate poses, each counted once.

Threads run over (view, ray) pairs. A ray walks the voxel grid from the sensor (exactly, as
planner ray casts do) and sees every voxel it enters before its range, up to and including
the first OCCUPIED one. Views are grouped (one view, or the views sampled along an edge); each
group owns a segment of an open-addressing hash set of voxel keys, and a voxel counts toward
its group's unknown / free / occupied totals only when it is first inserted. The set is exact
and the state is a property of the voxel, so the totals never depend on thread order.

With count_frontier, an UNKNOWN voxel first seen is also counted in a fourth total when one of
its six face neighbours is FREE: a frontier voxel, on the boundary of the water already seen
(FUEL's frontier cells). Frontier voxels lie where free space was measured, so none lies behind
a surface no beam has crossed.
"""

import warp as wp

from .hashing import hash_key, pack_block
from .planner_maps import FREE, OCCUPIED, UNKNOWN, MapAccess, state_of, store_slot, voxel_value
from .submap_view import voxel_centre
from .traversal import ray_walk_begin, walk_step

wp.set_module_options({"enable_backward": False})

EMPTY = wp.constant(wp.int64(-1))
# voxel offsets from a group's anchor are packed 21 bits per axis, like block keys
OFFSET_LIMIT = 1 << 20


@wp.func
def insert_voxel(tables: wp.array(dtype=wp.int64), base: int, capacity: int, key: wp.int64, max_probes: int) -> int:
    """1 if `key` was new to the set in tables[base:base+capacity], 0 if present, -1 if it
    found no place within max_probes probes (-1: any number)."""
    i = int(hash_key(key) & wp.uint32(capacity - 1))
    probes = capacity
    if max_probes >= 0:
        probes = wp.min(probes, max_probes)
    for _probe in range(probes):
        k = tables[base + i]
        if k == key:
            return 0
        if k == EMPTY:
            previous = wp.atomic_cas(tables, base + i, EMPTY, key)
            if previous == EMPTY:
                return 1
            if previous == key:
                return 0
        i = (i + 1) & (capacity - 1)
    return -1


@wp.func
def inside(p: wp.vec3d, lo: wp.vec3d, hi: wp.vec3d) -> bool:
    return p[0] >= lo[0] and p[0] <= hi[0] and p[1] >= lo[1] and p[1] <= hi[1] and p[2] >= lo[2] and p[2] <= hi[2]


@wp.func
def on_frontier(m: MapAccess, voxel: wp.vec3i, candidates: wp.array(dtype=wp.int32), first: int, last: int) -> bool:
    """Is one of the voxel's six face neighbours FREE?"""
    for k in range(6):
        axis = k / 2
        neighbour = wp.vec3i(voxel[0], voxel[1], voxel[2])
        neighbour[axis] = neighbour[axis] + 2 * (k % 2) - 1
        value = voxel_value(m, neighbour, store_slot(m, neighbour), candidates, first, last)
        if state_of(m, value) == FREE:
            return True
    return False


@wp.kernel
def count_seen_voxels(
    first_view: int,
    origins: wp.array(dtype=wp.vec3d),
    rotations: wp.array(dtype=wp.mat33d),
    groups: wp.array(dtype=wp.int32),
    directions: wp.array(dtype=wp.vec3d),
    max_range: wp.float64,
    min_range: wp.float64,
    use_region: int,
    region_lo: wp.vec3d,
    region_hi: wp.vec3d,
    m: MapAccess,
    candidate_offsets: wp.array(dtype=wp.int32),
    candidates: wp.array(dtype=wp.int32),
    table_offsets: wp.array(dtype=wp.int64),
    anchors: wp.array(dtype=wp.vec3i),
    tables: wp.array(dtype=wp.int64),
    max_probes: int,
    count_frontier: int,
    counted_states: int,
    counts: wp.array2d(dtype=wp.int32),
    overflow: wp.array(dtype=wp.int32),
):
    """counts[group, state] += the voxels of each state first seen by the group's rays;
    counts[group, 3] += the unknown ones on the frontier, when count_frontier.

    A voxel is seen if the ray enters it before max_range and leaves it beyond min_range (the
    sensor's blind distance); with use_region, only voxels whose centre lies in [region_lo,
    region_hi] count; only voxels of the states whose bit (1 << state) is set in counted_states
    are counted (and put in the set: a caller that reads only the unknown totals pays no
    insertions for the free voxels its rays cross). Rays still stop at occupied
    voxels they do not count. overflow[group] counts voxels its set found no place for within
    max_probes (its counts are then void)."""
    v, r = wp.tid()
    v = v + first_view
    group = groups[v]
    base = int(table_offsets[group])
    capacity = int(table_offsets[group + 1] - table_offsets[group])
    anchor = anchors[group]
    first = candidate_offsets[v]
    last = candidate_offsets[v + 1]
    w = ray_walk_begin(origins[v], rotations[v] * directions[r], m.resolution, m.inv_resolution, max_range)
    voxel, t_max, t_entry = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    slot = int(-1)
    new_block = bool(True)
    steps = int(0)
    while t_entry < max_range and steps <= w.max_steps:
        if new_block:
            slot = store_slot(m, voxel)
        state = state_of(m, voxel_value(m, voxel, slot, candidates, first, last))
        t_exit = wp.min(wp.min(t_max[0], t_max[1]), t_max[2])
        counted = t_exit > min_range and ((counted_states >> state) & 1) != 0
        if counted and use_region != 0:
            counted = inside(voxel_centre(voxel, m.resolution), region_lo, region_hi)
        if counted:
            offset = wp.vec3i(voxel[0] - anchor[0], voxel[1] - anchor[1], voxel[2] - anchor[2])
            added = insert_voxel(tables, base, capacity, pack_block(offset), max_probes)
            if added == 1:
                wp.atomic_add(counts, group, state, 1)
                if count_frontier != 0 and state == UNKNOWN:
                    if on_frontier(m, voxel, candidates, first, last):
                        wp.atomic_add(counts, group, 3, 1)
            elif added < 0:
                wp.atomic_add(overflow, group, 1)
        if state == OCCUPIED:
            break
        voxel, t_max, t_entry, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
