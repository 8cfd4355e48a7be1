"""Scan integration with OctoMap `insertPointCloud` semantics, batched over many scans.

A pass integrates up to a few hundred scans (256 on a CPU, 2048 on a GPU) in two launches:
1. `mark_beams`, over rays: walk each beam once and set, per voxel and scan, a "free" or
   "occupied" bit (two bits per scan, 32 scans per uint64 word) in the scratch marks of the
   voxel's block. OR-ing bits gives every voxel at most one update per scan with occupied
   winning, whatever order the rays run in. Blocks are numbered as the pass meets them, found by
   their cell in the pass's bounding box (one load), or, when the box is too large to index,
   in an open-addressing table.
2. `apply_marks` (`apply_marks_few_words` on a CPU, for up to 8 words per voxel), over the
   voxels of the blocks the pass numbered (the host allocates their map blocks in between):
   replay the scans in order per voxel, adding the hit or miss log-odds and clamping after each,
   exactly the sequence single-scan integration would apply (a voxel held at a clamp skips the
   updates that cannot move it). It clears the marks and table entries it read, so the scratch
   is clean for the next pass without a memset.

Marks are stored word-plane by word-plane (`(word * capacity + block) * 512 + voxel`): the rays
run in scan order, so 32 scans at a time touch one plane only.

On the CPU a launch is split over threads, each with a scratch of its own (`part`): CPU atomics
are plain read-modify-writes. The replay ORs the parts' marks of a block before replaying.
"""

import warp as wp

from .hashing import BLOCK_VOXELS, EMPTY_KEY, block_of, first_probe, index_in_block, observed, pack_block
from .levels import cell_bit, same_value
from .traversal import VoxelWalk, norm_like_octomap, segment_continues, segment_walk_begin, voxel_key, walk_step

wp.set_module_options({"enable_backward": False})

SCANS_PER_WORD = 32
# Scratch table entries (table_index): not numbered yet, being numbered by another thread
# (CUDA only), and numbered beyond the scratch's capacity (the host reruns the pass).
UNCLAIMED = wp.constant(-1)
NUMBERING = wp.constant(-2)
FULL = wp.constant(-3)
# A reader waits at most this many polls for a number being written (a few on CUDA).
MAX_POLLS = wp.constant(1 << 20)
PAIR_MASK = wp.constant(wp.uint64(0x5555555555555555))  # the free bit of every scan's pair


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
def walk_of_beam(origin: wp.vec3f, end: wp.vec4f, resolution: wp.float64, inv_resolution: wp.float64) -> VoxelWalk:
    return segment_walk_begin(origin, wp.vec3f(end[0], end[1], end[2]), resolution, inv_resolution)


@wp.func
def published_number(table_index: wp.array(dtype=wp.int32), i: int, wait_unclaimed: bool) -> int:
    """A block's number once its numbering thread has written it (at once on the CPU); -1 if
    the scratch was full."""
    c = table_index[i]
    polls = int(0)
    while (c == NUMBERING or (wait_unclaimed and c == UNCLAIMED)) and polls < MAX_POLLS:
        c = wp.atomic_add(table_index, i, 0)
        polls += 1
    return wp.where(c < 0, -1, c)


@wp.func
def number_block(
    block: wp.vec3i,
    i: int,
    capacity: int,
    table_index: wp.array(dtype=wp.int32),
    table_position: wp.array(dtype=wp.int32),
    block_keys: wp.array(dtype=wp.int64),
    counters: wp.array(dtype=wp.int32),
) -> int:
    """Give the block at table entry i the pass's next number and publish it (FULL beyond
    `capacity`; counters[0] still counts it, so the host knows how much room to make)."""
    c = wp.atomic_add(counters, 0, 1)
    if c < capacity:
        block_keys[c] = pack_block(block)
        table_position[c] = i
    else:
        c = FULL
    wp.atomic_exch(table_index, i, c)
    return wp.where(c < 0, -1, c)


@wp.func
def dense_block(
    block: wp.vec3i,
    cell: int,
    capacity: int,
    table_index: wp.array(dtype=wp.int32),
    table_position: wp.array(dtype=wp.int32),
    block_keys: wp.array(dtype=wp.int64),
    counters: wp.array(dtype=wp.int32),
) -> int:
    """Number of the block in box cell `cell` (its table entry), numbering it if new; -1 if full."""
    if wp.atomic_cas(table_index, cell, UNCLAIMED, NUMBERING) == UNCLAIMED:
        return number_block(block, cell, capacity, table_index, table_position, block_keys, counters)
    return published_number(table_index, cell, False)


@wp.func
def box_cell(voxel: wp.vec3i, box_lo: wp.vec3i, box_dims: wp.vec3i) -> int:
    """Cell of the voxel's block in the pass's box (blocks box_lo + [0, box_dims)); -1 outside."""
    x = (voxel[0] >> 3) - box_lo[0]
    y = (voxel[1] >> 3) - box_lo[1]
    z = (voxel[2] >> 3) - box_lo[2]
    if x < 0 or y < 0 or z < 0 or x >= box_dims[0] or y >= box_dims[1] or z >= box_dims[2]:
        return -1
    return (x * box_dims[1] + y) * box_dims[2] + z


@wp.func
def hashed_block(
    block: wp.vec3i,
    capacity: int,
    table_keys: wp.array(dtype=wp.int64),
    table_index: wp.array(dtype=wp.int32),
    table_position: wp.array(dtype=wp.int32),
    block_keys: wp.array(dtype=wp.int64),
    counters: wp.array(dtype=wp.int32),
) -> int:
    """Number of `block` in the hashed scratch table, numbering it if new; -1 when the scratch
    is full (counters[0] above the capacity, or counters[1] > 0: no free table entry)."""
    key = pack_block(block)
    size = table_keys.shape[0]
    i = first_probe(key, size)
    for _probe in range(size):
        k = table_keys[i]
        if k == EMPTY_KEY:
            k = wp.atomic_cas(table_keys, i, EMPTY_KEY, key)
            if k == EMPTY_KEY:
                return number_block(block, i, capacity, table_index, table_position, block_keys, counters)
        if k == key:
            return published_number(table_index, i, True)
        i = (i + 1) & (size - 1)
    wp.atomic_add(counters, 1, 1)
    return -1


@wp.func
def block_base(
    x: int,
    y: int,
    z: int,
    box_lo: wp.vec3i,
    box_dims: wp.vec3i,
    plane: int,
    capacity: int,
    table_keys: wp.array(dtype=wp.int64),
    table_index: wp.array(dtype=wp.int32),
    table_position: wp.array(dtype=wp.int32),
    block_keys: wp.array(dtype=wp.int64),
    counters: wp.array(dtype=wp.int32),
) -> int:
    """Marks index of voxel 0 of the block of voxel (x, y, z) in the scan's word plane; -1 when
    it has no number (scratch full, or outside the dense box: counters[1] then tells the host)."""
    v = wp.vec3i(x, y, z)
    c = int(-1)
    if box_dims[0] > 0:
        cell = box_cell(v, box_lo, box_dims)
        if cell < 0:
            wp.atomic_add(counters, 1, 1)
            return -1
        c = table_index[cell]
        if c < 0:
            c = dense_block(block_of(v), cell, capacity, table_index, table_position, block_keys, counters)
    else:
        c = hashed_block(block_of(v), capacity, table_keys, table_index, table_position, block_keys, counters)
    return wp.where(c < 0, -1, plane + c * BLOCK_VOXELS)


@wp.kernel
def mark_beams(
    origins: wp.array(dtype=wp.vec3f),
    points: wp.array(dtype=wp.vec3f),
    ray_scan: wp.array(dtype=wp.int32),
    first_scan: int,
    max_range: wp.float64,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    box_lo: wp.vec3i,
    box_dims: wp.vec3i,
    capacity: int,
    table_keys: wp.array(dtype=wp.int64),
    table_index: wp.array(dtype=wp.int32),
    table_position: wp.array(dtype=wp.int32),
    block_keys: wp.array(dtype=wp.int64),
    counters: wp.array(dtype=wp.int32),
    marks: wp.array(dtype=wp.uint64),
):
    """Per beam: a free bit for every voxel it crosses and a hit bit for its endpoint voxel.

    Blocks are numbered through the box cell table when box_dims > 0 (a voxel outside the box,
    only possible if round-off carried a walk past its margin, counts in counters[1] and the
    host reruns the pass hashed), else through the hash table. The walk is segment_walk_begin's
    and walk_step's, written out on scalars: the block and the index in it follow each step
    incrementally, and a block is looked up only when a step crosses into a new one.
    """
    tid = wp.tid()
    scan = ray_scan[tid]
    origin = origins[scan]
    scan = scan - first_scan
    free_bit = wp.uint64(1) << wp.uint64(2 * (scan & 31))
    plane = (scan >> 5) * capacity * BLOCK_VOXELS
    end = beam_end(origin, points[tid], max_range)
    w = walk_of_beam(origin, end, resolution, inv_resolution)
    x, y, z = w.voxel[0], w.voxel[1], w.voxel[2]
    tx, ty, tz = w.t_max[0], w.t_max[1], w.t_max[2]
    dx, dy, dz = w.t_delta[0], w.t_delta[1], w.t_delta[2]
    sx, sy, sz = w.step[0], w.step[1], w.step[2]
    # stepping up enters a block at local coordinate 0, stepping down at 7
    ex, ey, ez = (sx >> 1) & 7, (sy >> 1) & 7, (sz >> 1) & 7
    active = bool(w.active)
    steps = int(0)
    base = int(-1)
    if active:
        base = block_base(
            x, y, z, box_lo, box_dims, plane, capacity, table_keys, table_index, table_position, block_keys, counters
        )
    while active:
        if base >= 0:
            wp.atomic_or(marks, base + (((x & 7) << 6) | ((y & 7) << 3) | (z & 7)), free_bit)
        crossed = bool(False)
        # walk_step's choice (OctoMap's tie-breaking), then segment_continues
        if tx < ty and tx < tz:
            x += sx
            tx += dx
            crossed = (x & 7) == ex
        elif ty < tz:
            y += sy
            ty += dy
            crossed = (y & 7) == ey
        else:
            z += sz
            tz += dz
            crossed = (z & 7) == ez
        steps += 1
        active = (
            (x != w.last[0] or y != w.last[1] or z != w.last[2])
            and wp.min(wp.min(tx, ty), tz) <= w.length
            and steps <= w.max_steps
        )
        if active and crossed:
            base = block_base(
                x,
                y,
                z,
                box_lo,
                box_dims,
                plane,
                capacity,
                table_keys,
                table_index,
                table_position,
                block_keys,
                counters,
            )
    if end[3] > 0.0:
        v = voxel_key(wp.vec3f(end[0], end[1], end[2]), inv_resolution)
        b = block_base(
            v[0],
            v[1],
            v[2],
            box_lo,
            box_dims,
            plane,
            capacity,
            table_keys,
            table_index,
            table_position,
            block_keys,
            counters,
        )
        if b >= 0:
            wp.atomic_or(marks, b + index_in_block(v), free_bit << wp.uint64(1))


@wp.kernel
def count_beam_voxels(
    origins: wp.array(dtype=wp.vec3f),
    points: wp.array(dtype=wp.vec3f),
    ray_scan: wp.array(dtype=wp.int32),
    max_range: wp.float64,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    counts: wp.array(dtype=wp.int32),
):
    """Voxels each beam marks (the free ones it crosses, plus its endpoint if a hit), by the
    plain walk of traversal.py: the work integration cannot avoid, for profiles."""
    tid = wp.tid()
    origin = origins[ray_scan[tid]]
    end = beam_end(origin, points[tid], max_range)
    w = walk_of_beam(origin, end, resolution, inv_resolution)
    voxel, t_max = wp.vec3i(w.voxel), wp.vec3d(w.t_max)
    active, steps = bool(w.active), int(0)
    while active:
        voxel, t_max, _t, _new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
        active = segment_continues(voxel, t_max, w, steps)
    counts[tid] = steps + wp.where(end[3] > 0.0, 1, 0)


@wp.func
def lowest_bit(x: wp.uint64) -> wp.uint64:
    return x & (~x + wp.uint64(1))


@wp.func
def replay_word(
    value: wp.float32,
    m: wp.uint64,
    log_hit: wp.float32,
    log_miss: wp.float32,
    clamp_min: wp.float32,
    clamp_max: wp.float32,
) -> wp.float32:
    """`value` after the scans marked in word `m` (two bits per scan, free then occupied), in
    order, with OctoMap's clamped update."""
    touched = (m | (m >> wp.uint64(1))) & PAIR_MASK  # one bit per marked scan, in order
    hits = (m >> wp.uint64(1)) & PAIR_MASK  # occupied wins over free within a scan
    while touched != wp.uint64(0):
        # At a clamp, the updates pushing further out leave the value as it is: go on from the
        # next scan that pulls it back.
        if value == clamp_min:
            touched = touched & ~(lowest_bit(touched & hits) - wp.uint64(1))
        elif value == clamp_max:
            touched = touched & ~(lowest_bit(touched & ~hits) - wp.uint64(1))
        low = lowest_bit(touched)
        if low != wp.uint64(0):
            touched = touched ^ low
            update = wp.where((hits & low) != wp.uint64(0), log_hit, log_miss)
            # OctoMap clamps after every update (lower bound first: the same as min(max(.))
            # for clamp_min < clamp_max)
            value = wp.min(wp.max(value + update, clamp_min), clamp_max)
    return value


@wp.func
def value_before(slot: int, log_odds: wp.array(dtype=wp.float32)) -> wp.float32:
    value = log_odds[slot]
    if not observed(value):
        value = wp.float32(0.0)
    return value


@wp.func
def note_changed_cell(
    u: int, voxel: int, before: wp.float32, after: wp.float32, record: int, cell_masks: wp.array(dtype=wp.uint64)
):
    """With `record`, set in cell_masks[u] the bit of the 2x2x2 cell of voxel number `voxel`
    (`index_in_block`) when its log-odds changed bits: the cells the coarse levels must
    recompute (`levels.cell_bit`)."""
    if record != 0 and not same_value(before, after):
        wp.atomic_or(cell_masks, u, cell_bit(wp.vec3i(voxel >> 6, (voxel >> 3) & 7, voxel & 7)))


@wp.func
def release_entries(
    u: int,
    part_blocks: wp.array2d(dtype=wp.int32),
    table_keys: wp.array2d(dtype=wp.int64),
    table_index: wp.array2d(dtype=wp.int32),
    table_position: wp.array2d(dtype=wp.int32),
):
    """Empty the scratch table entries of touched block u, in every part that numbered it."""
    for part in range(part_blocks.shape[1]):
        c = part_blocks[u, part]
        if c >= 0:
            position = table_position[part, c]
            table_keys[part, position] = EMPTY_KEY
            table_index[part, position] = UNCLAIMED


@wp.kernel
def apply_marks(
    block_slots: wp.array(dtype=wp.int32),
    part_blocks: wp.array2d(dtype=wp.int32),
    first: int,
    words_per_voxel: int,
    capacity: int,
    log_hit: wp.float32,
    log_miss: wp.float32,
    clamp_min: wp.float32,
    clamp_max: wp.float32,
    marks: wp.array2d(dtype=wp.uint64),
    table_keys: wp.array2d(dtype=wp.int64),
    table_index: wp.array2d(dtype=wp.int32),
    table_position: wp.array2d(dtype=wp.int32),
    record: int,
    log_odds: wp.array(dtype=wp.float32),
    cell_masks: wp.array(dtype=wp.uint64),
):
    """Per voxel of the touched blocks (block u = map slot block_slots[u], numbered
    part_blocks[u, p] in scratch part p, -1 where that part did not touch it): replay the marked
    scans in order, then clear the marks read (and, once per block, its table entries). With
    `record`, the cells whose voxels changed are ORed into cell_masks[u] (zeroed before)."""
    tid = first + wp.tid()
    u = tid // BLOCK_VOXELS
    voxel = tid - u * BLOCK_VOXELS
    i = int(0)
    value = wp.float32(0.0)
    before = wp.float32(0.0)
    marked = bool(False)
    for word in range(words_per_voxel):
        m = wp.uint64(0)
        for part in range(part_blocks.shape[1]):
            c = part_blocks[u, part]
            if c >= 0:
                j = (word * capacity + c) * BLOCK_VOXELS + voxel
                bits = marks[part, j]
                if bits != wp.uint64(0):
                    m = m | bits
                    marks[part, j] = wp.uint64(0)
        if m != wp.uint64(0):
            if not marked:  # the map is read only for voxels the pass marked
                marked = True
                i = block_slots[u] * BLOCK_VOXELS + voxel
                before = log_odds[i]
                value = value_before(i, log_odds)
            value = replay_word(value, m, log_hit, log_miss, clamp_min, clamp_max)
    if marked:
        log_odds[i] = value
        note_changed_cell(u, voxel, before, value, record, cell_masks)
    if voxel == 0:
        release_entries(u, part_blocks, table_keys, table_index, table_position)


# The most words per voxel apply_marks_few_words takes (CPU passes of up to 256 scans).
FEW_WORDS = wp.constant(8)
few_words = wp.types.vector(length=FEW_WORDS, dtype=wp.uint64)


@wp.kernel
def apply_marks_few_words(
    block_slots: wp.array(dtype=wp.int32),
    part_blocks: wp.array2d(dtype=wp.int32),
    first: int,
    words_per_voxel: int,
    capacity: int,
    log_hit: wp.float32,
    log_miss: wp.float32,
    clamp_min: wp.float32,
    clamp_max: wp.float32,
    marks: wp.array2d(dtype=wp.uint64),
    table_keys: wp.array2d(dtype=wp.int64),
    table_index: wp.array2d(dtype=wp.int32),
    table_position: wp.array2d(dtype=wp.int32),
    record: int,
    log_odds: wp.array(dtype=wp.float32),
    cell_masks: wp.array(dtype=wp.uint64),
):
    """apply_marks for passes of at most FEW_WORDS words per voxel: each part's block number is
    read once and its words gathered into registers (loops unrolled), then replayed in order.
    Most voxels of a touched block carry no mark, so the gathering is most of the work (a CPU
    thread took about half the time per voxel this way)."""
    tid = first + wp.tid()
    u = tid // BLOCK_VOXELS
    voxel = tid - u * BLOCK_VOXELS
    plane = capacity * BLOCK_VOXELS
    zero = wp.uint64(0)
    m = few_words()
    for part in range(part_blocks.shape[1]):
        c = part_blocks[u, part]
        if c >= 0:
            j = c * BLOCK_VOXELS + voxel
            for word in range(FEW_WORDS):
                if word < words_per_voxel:
                    bits = marks[part, j + word * plane]
                    if bits != zero:
                        m[word] = m[word] | bits
                        marks[part, j + word * plane] = zero
    marked = zero
    for word in range(FEW_WORDS):
        marked = marked | m[word]
    if marked != zero:  # the map is read only for voxels the pass marked
        i = block_slots[u] * BLOCK_VOXELS + voxel
        before = log_odds[i]
        value = value_before(i, log_odds)
        for word in range(FEW_WORDS):
            value = replay_word(value, m[word], log_hit, log_miss, clamp_min, clamp_max)
        log_odds[i] = value
        note_changed_cell(u, voxel, before, value, record, cell_masks)
    if voxel == 0:
        release_entries(u, part_blocks, table_keys, table_index, table_position)
