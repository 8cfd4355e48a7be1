"""Scan integration with OctoMap `insertPointCloud` semantics, batched over many scans.

A batch of scans is integrated in three passes, all over rays:
1. `list_ray_blocks`: walk each beam, record the blocks it touches (so they can be allocated).
2. `mark_ray_voxels`: walk again and set, per touched voxel and scan, a "free" or "occupied" bit
   (two bits per scan, 32 scans per uint64 word). OR-ing bits makes every voxel take at most one
   update per scan with occupied winning, whatever order the rays run in.
3. `apply_marks`: per touched voxel, replay the scans in order: add the hit or miss log-odds and
   clamp after each. This is exactly the sequence single-scan integration would apply.
"""

import warp as wp

from .hashing import BLOCK_VOXELS, EMPTY_KEY, block_of, find_slot, index_in_block, pack_block
from .traversal import (VoxelWalk, norm_like_octomap, same_voxel, segment_continues, segment_walk_begin,
                        voxel_key, walk_step)

wp.set_module_options({"enable_backward": False})

SCANS_PER_WORD = 32


@wp.func
def beam_end(origin: wp.vec3f, point: wp.vec3f, max_range: wp.float64) -> wp.vec4f:
    """End of the free-space segment (xyz) and 1 if the beam's endpoint is a hit (w).

    Like OctoMap: a beam longer than max_range is cut to max_range along its float32 direction.
    """
    d = wp.vec3f(point[0] - origin[0], point[1] - origin[1], point[2] - origin[2])
    norm = norm_like_octomap(d)
    if norm <= max_range:
        return wp.vec4f(point[0], point[1], point[2], 1.0)
    n = wp.float32(norm)
    r = wp.float32(max_range)
    e = wp.vec3f(0.0, 0.0, 0.0)
    for i in range(3):
        direction = d[i] / n
        reach = direction * r
        e[i] = origin[i] + reach
    return wp.vec4f(e[0], e[1], e[2], 0.0)


@wp.func
def walk_of_beam(origin: wp.vec3f, end: wp.vec4f, resolution: wp.float64,
                 inv_resolution: wp.float64) -> VoxelWalk:
    return segment_walk_begin(origin, wp.vec3f(end[0], end[1], end[2]), resolution, inv_resolution)


@wp.kernel
def list_ray_blocks(origins: wp.array(dtype=wp.vec3f), points: wp.array(dtype=wp.vec3f),
                    ray_scan: wp.array(dtype=wp.int32), max_range: wp.float64,
                    resolution: wp.float64, inv_resolution: wp.float64,
                    block_keys: wp.array2d(dtype=wp.int64), block_counts: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    origin = origins[ray_scan[tid]]
    end = beam_end(origin, points[tid], max_range)
    w = walk_of_beam(origin, end, resolution, inv_resolution)
    capacity = block_keys.shape[1]
    n = int(0)
    current = block_of(w.voxel)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active, steps = bool(w.active), int(0)
    new_block = bool(True)
    while active:
        if new_block:
            current = block_of(voxel)
            if n < capacity:
                block_keys[tid, n] = pack_block(current)
            n += 1
        voxel, t_max, _t, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
        active = segment_continues(voxel, t_max, w, steps)
    if end[3] > 0.0:
        b = block_of(voxel_key(wp.vec3f(end[0], end[1], end[2]), inv_resolution))
        if n == 0 or not same_voxel(b, current):
            if n < capacity:
                block_keys[tid, n] = pack_block(b)
            n += 1
    block_counts[tid] = n


@wp.kernel
def claim_touched_blocks(keys: wp.array(dtype=wp.int64), table_keys: wp.array(dtype=wp.int64),
                         table_slots: wp.array(dtype=wp.int32), touch_index: wp.array(dtype=wp.int32),
                         touched_slots: wp.array(dtype=wp.int32), num_touched: wp.array(dtype=wp.int32)):
    """Number the distinct blocks of `keys`: touch_index[slot] = position in touched_slots."""
    tid = wp.tid()
    key = keys[tid]
    if key == EMPTY_KEY:
        return
    slot = find_slot(table_keys, table_slots, key)
    if wp.atomic_cas(touch_index, slot, -1, -2) == -1:
        c = wp.atomic_add(num_touched, 0, 1)
        touched_slots[c] = slot
        touch_index[slot] = c


@wp.kernel
def release_touched_blocks(touched_slots: wp.array(dtype=wp.int32), touch_index: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    touch_index[touched_slots[tid]] = -1


@wp.func
def mark_voxel(voxel: wp.vec3i, block_slot: int, touch_index: wp.array(dtype=wp.int32),
               words_per_voxel: int, word: int, bit: wp.uint64, marks: wp.array(dtype=wp.uint64)):
    if block_slot < 0:
        return
    compact = touch_index[block_slot]
    i = (compact * BLOCK_VOXELS + index_in_block(voxel)) * words_per_voxel + word
    wp.atomic_or(marks, i, bit)


@wp.kernel
def mark_ray_voxels(origins: wp.array(dtype=wp.vec3f), points: wp.array(dtype=wp.vec3f),
                    ray_scan: wp.array(dtype=wp.int32), max_range: wp.float64,
                    resolution: wp.float64, inv_resolution: wp.float64,
                    table_keys: wp.array(dtype=wp.int64), table_slots: wp.array(dtype=wp.int32),
                    touch_index: wp.array(dtype=wp.int32), words_per_voxel: int,
                    marks: wp.array(dtype=wp.uint64)):
    tid = wp.tid()
    scan = ray_scan[tid]
    origin = origins[scan]
    word = scan // SCANS_PER_WORD
    free_bit = wp.uint64(1) << wp.uint64(2 * (scan % SCANS_PER_WORD))
    hit_bit = free_bit << wp.uint64(1)
    end = beam_end(origin, points[tid], max_range)
    w = walk_of_beam(origin, end, resolution, inv_resolution)
    slot = int(-1)
    current = block_of(w.voxel)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active, steps = bool(w.active), int(0)
    new_block = bool(True)
    while active:
        if new_block:
            current = block_of(voxel)
            slot = find_slot(table_keys, table_slots, pack_block(current))
        mark_voxel(voxel, slot, touch_index, words_per_voxel, word, free_bit, marks)
        voxel, t_max, _t, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
        active = segment_continues(voxel, t_max, w, steps)
    if end[3] > 0.0:
        v = voxel_key(wp.vec3f(end[0], end[1], end[2]), inv_resolution)
        b = block_of(v)
        if slot < 0 or not same_voxel(b, current):
            slot = find_slot(table_keys, table_slots, pack_block(b))
        mark_voxel(v, slot, touch_index, words_per_voxel, word, hit_bit, marks)


@wp.kernel
def apply_marks(touched_slots: wp.array(dtype=wp.int32), first: int, marks: wp.array2d(dtype=wp.uint64),
                words_per_voxel: int, log_hit: wp.float32, log_miss: wp.float32,
                clamp_min: wp.float32, clamp_max: wp.float32, log_odds: wp.array(dtype=wp.float32)):
    tid = first + wp.tid()  # voxel among the touched blocks' voxels
    compact = tid // BLOCK_VOXELS
    i = touched_slots[compact] * BLOCK_VOXELS + tid % BLOCK_VOXELS
    value = log_odds[i]
    changed = bool(False)
    for word in range(words_per_voxel):
        m = wp.uint64(0)
        for copy in range(marks.shape[0]):  # one copy per CPU thread that marked
            m = m | marks[copy, tid * words_per_voxel + word]
        for _scan in range(SCANS_PER_WORD):
            if m == wp.uint64(0):
                break
            bits = m & wp.uint64(3)
            m = m >> wp.uint64(2)
            if bits != wp.uint64(0):
                if not changed:
                    changed = True
                    if wp.isnan(value):
                        value = wp.float32(0.0)
                if bits >= wp.uint64(2):
                    value = value + log_hit
                else:
                    value = value + log_miss
                # OctoMap's order: the lower bound first.
                if value < clamp_min:
                    value = clamp_min
                elif value > clamp_max:
                    value = clamp_max
    if changed:
        log_odds[i] = value
