"""Open-addressing hash table from integer block coordinates to block slots.

A block is an 8x8x8 cube of voxels. Its coordinates (voxel key >> 3 on each axis) are packed
into one int64, 21 bits per axis, so the table compares and swaps single words. Linear probing;
the host keeps the load factor at or below one half, so every probe loop ends.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

BLOCK_EDGE = 8
BLOCK_VOXELS = 512
EMPTY_KEY = wp.constant(wp.int64(-1))
# A released block's table entry: probes pass over it, insertions do not reuse it (a rehash
# clears them), so concurrent inserts never place one key twice.
TOMBSTONE_KEY = wp.constant(wp.int64(-2))
# Voxel keys must lie in [-VOXEL_KEY_LIMIT, VOXEL_KEY_LIMIT) so that block coordinates fit 21 bits.
VOXEL_KEY_LIMIT = 1 << 23
VOXEL_KEY_LIMIT_C = wp.constant(VOXEL_KEY_LIMIT)
BLOCK_BIAS = wp.constant(1 << 20)
FIELD_MASK = wp.constant(wp.int64((1 << 21) - 1))


@wp.func
def observed(value: wp.float32) -> bool:
    """False for NaN, the value of a voxel nobody observed. (wp.isnan is a call into Warp's
    runtime on the CPU, not inlined: in an inner loop it costs more than the loop's work.)"""
    return value == value


@wp.func
def block_of(voxel: wp.vec3i) -> wp.vec3i:
    # Arithmetic shift floors negative keys too.
    return wp.vec3i(voxel[0] >> 3, voxel[1] >> 3, voxel[2] >> 3)


@wp.func
def index_in_block(voxel: wp.vec3i) -> int:
    return ((voxel[0] & 7) * 8 + (voxel[1] & 7)) * 8 + (voxel[2] & 7)


@wp.func
def voxel_key_in_range(voxel: wp.vec3i) -> bool:
    lim = VOXEL_KEY_LIMIT_C
    return (
        voxel[0] >= -lim
        and voxel[0] < lim
        and voxel[1] >= -lim
        and voxel[1] < lim
        and voxel[2] >= -lim
        and voxel[2] < lim
    )


@wp.func
def pack_block(block: wp.vec3i) -> wp.int64:
    x = wp.int64(block[0] + BLOCK_BIAS)
    y = wp.int64(block[1] + BLOCK_BIAS)
    z = wp.int64(block[2] + BLOCK_BIAS)
    return (x << wp.int64(42)) | (y << wp.int64(21)) | z


@wp.func
def unpack_block(key: wp.int64) -> wp.vec3i:
    return wp.vec3i(
        int((key >> wp.int64(42)) & FIELD_MASK) - BLOCK_BIAS,
        int((key >> wp.int64(21)) & FIELD_MASK) - BLOCK_BIAS,
        int(key & FIELD_MASK) - BLOCK_BIAS,
    )


@wp.func
def mix32(x: wp.uint32) -> wp.uint32:
    # Integer finaliser (two multiply-xorshift rounds): spreads neighbouring blocks apart.
    h = ((x >> wp.uint32(16)) ^ x) * wp.uint32(0x45D9F3B)
    h = ((h >> wp.uint32(16)) ^ h) * wp.uint32(0x45D9F3B)
    return (h >> wp.uint32(16)) ^ h


@wp.func
def hash_key(key: wp.int64) -> wp.uint32:
    x = wp.uint32((key >> wp.int64(42)) & FIELD_MASK)
    y = wp.uint32((key >> wp.int64(21)) & FIELD_MASK)
    z = wp.uint32(key & FIELD_MASK)
    return mix32(x * wp.uint32(73856093) ^ y * wp.uint32(19349663) ^ z * wp.uint32(83492791))


@wp.func
def first_probe(key: wp.int64, capacity: int) -> int:
    return int(hash_key(key) & wp.uint32(capacity - 1))


@wp.func
def find_slot(table_keys: wp.array(dtype=wp.int64), table_slots: wp.array(dtype=wp.int32), key: wp.int64) -> int:
    """Slot of the block with packed coordinates `key`, or -1 if the table lacks it."""
    capacity = table_keys.shape[0]
    i = first_probe(key, capacity)
    for _probe in range(capacity):
        k = table_keys[i]
        if k == key:
            return table_slots[i]
        if k == EMPTY_KEY:
            return -1
        i = (i + 1) & (capacity - 1)
    return -1


@wp.func
def find_voxel_slot(
    table_keys: wp.array(dtype=wp.int64), table_slots: wp.array(dtype=wp.int32), voxel: wp.vec3i
) -> int:
    if not voxel_key_in_range(voxel):
        return -1
    return find_slot(table_keys, table_slots, pack_block(block_of(voxel)))


# Probes an insertion may take before it gives up; the host then grows the table and retries.
MAX_INSERT_PROBES = wp.constant(128)


@wp.kernel
def insert_keys(
    keys: wp.array(dtype=wp.int64),
    table_keys: wp.array(dtype=wp.int64),
    new_positions: wp.array(dtype=wp.int32),
    counters: wp.array(dtype=wp.int32),
):
    """Insert packed keys; list where new ones landed (counters[0]); counters[1] += failures.
    Once an insertion has failed (the table is too full), the rest fail at once: the host grows
    the table and inserts again, rather than every key probing a full table."""
    tid = wp.tid()
    key = keys[tid]
    if key == EMPTY_KEY:
        return
    if counters[1] > 0:
        wp.atomic_add(counters, 1, 1)
        return
    capacity = table_keys.shape[0]
    i = first_probe(key, capacity)
    for _probe in range(MAX_INSERT_PROBES):
        k = table_keys[i]
        if k == key:
            return
        if k == EMPTY_KEY:
            previous = wp.atomic_cas(table_keys, i, EMPTY_KEY, key)
            if previous == EMPTY_KEY:
                new_positions[wp.atomic_add(counters, 0, 1)] = i
                return
            if previous == key:
                return
        i = (i + 1) & (capacity - 1)
    wp.atomic_add(counters, 1, 1)


@wp.kernel
def assign_slots(
    new_positions: wp.array(dtype=wp.int32),
    reused: wp.array(dtype=wp.int32),
    fresh_from: int,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    slot_keys: wp.array(dtype=wp.int64),
):
    """Give the tid-th new key slot reused[tid], or past them fresh_from + (tid - len(reused))."""
    tid = wp.tid()
    position = new_positions[tid]
    slot = int(0)
    if tid < reused.shape[0]:
        slot = reused[tid]
    else:
        slot = fresh_from + tid - reused.shape[0]
    table_slots[position] = slot
    slot_keys[slot] = table_keys[position]


@wp.kernel
def reinsert_slots(
    slot_keys: wp.array(dtype=wp.int64), table_keys: wp.array(dtype=wp.int64), table_slots: wp.array(dtype=wp.int32)
):
    tid = wp.tid()
    key = slot_keys[tid]
    if key == EMPTY_KEY:
        return
    capacity = table_keys.shape[0]
    i = first_probe(key, capacity)
    for _probe in range(capacity):
        if wp.atomic_cas(table_keys, i, EMPTY_KEY, key) == EMPTY_KEY:
            table_slots[i] = tid
            return
        i = (i + 1) & (capacity - 1)


@wp.kernel
def resolve_slots(
    keys: wp.array(dtype=wp.int64),
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    key = keys[tid]
    slots[tid] = -1
    if key != EMPTY_KEY:
        slots[tid] = find_slot(table_keys, table_slots, key)


@wp.kernel
def remove_slots(
    slots: wp.array(dtype=wp.int32),
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    slot_keys: wp.array(dtype=wp.int64),
):
    tid = wp.tid()
    slot = slots[tid]
    key = slot_keys[slot]
    capacity = table_keys.shape[0]
    i = first_probe(key, capacity)
    for _probe in range(capacity):
        if table_keys[i] == key:
            table_keys[i] = TOMBSTONE_KEY
            table_slots[i] = -1
            slot_keys[slot] = EMPTY_KEY
            return
        i = (i + 1) & (capacity - 1)


@wp.kernel
def fill_block_grid(slot_keys: wp.array(dtype=wp.int64), lo: wp.vec3i, dims: wp.vec3i, grid: wp.array(dtype=wp.int32)):
    """grid[cell of block b in the box lo + [0, dims)] = the slot holding b (query accelerator:
    a block look-up in one load, no probing)."""
    slot = wp.tid()
    key = slot_keys[slot]
    if key == EMPTY_KEY:
        return
    b = unpack_block(key)
    grid[((b[0] - lo[0]) * dims[1] + b[1] - lo[1]) * dims[2] + b[2] - lo[2]] = slot


@wp.func
def grid_slot(block: wp.vec3i, lo: wp.vec3i, dims: wp.vec3i, grid: wp.array(dtype=wp.int32)) -> int:
    """Slot of a block in a block grid (fill_block_grid); -1 outside it or where absent."""
    x = block[0] - lo[0]
    y = block[1] - lo[1]
    z = block[2] - lo[2]
    if x < 0 or y < 0 or z < 0 or x >= dims[0] or y >= dims[1] or z >= dims[2]:
        return -1
    return grid[(x * dims[1] + y) * dims[2] + z]
