"""Decoding OctoMap's serialised trees (the data of .bt and .ot files and of octomap_msgs).

Both streams are the tree in pre-order, children in index order (child i of a node holds key
bit b = 15 - depth of x, y, z as bits 0, 1, 2 of i). Walking the children in index order and
descending into an inner child when it is reached consumes the stream in its own order and
emits the leaves sorted by Morton code, which is what lets the host cut them into 8x8x8 blocks
without sorting. A leaf's code is its first voxel's: the node's prefix shifted to depth 16.

The walk is sequential (each node's place depends on every node before it): one thread, run on
the CPU, where a launch is compiled C++; it keeps its path from the root in small scratch
arrays (17 levels) and reports the first fault it finds rather than reading past it.

It also places each leaf in the block store the tree will fill (blocks in Morton order): the
slot of the leaf's block (a leaf of whole blocks: its first) in `rows`, and per leaf that opens
blocks a run (first block code, blocks) in `run_firsts`, `run_blocks`, so the host lists the
blocks from the runs alone and checks their number against its budget before allocating them.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

TREE_DEPTH = wp.constant(16)
# status[] of the decoders
STATUS_LEAVES = 0  # leaves written
STATUS_NODES = 1  # nodes read, the root included
STATUS_READ = 2  # bytes (binary) or records (full) consumed
STATUS_FAULT = 3  # one of the FAULT_* codes, 0 when the stream decoded
STATUS_WHERE = 4  # byte offset (binary) or record index (full) of the fault
STATUS_RUNS = 5  # runs of blocks written
STATUS_BLOCKS = 6  # blocks of all runs
STATUS_LAST_BLOCK = 7  # scratch: code of the last block placed (-1: none)
STATUS_SIZE = 8
FAULT_TRUNCATED = wp.constant(1)  # the stream ends inside the tree
FAULT_CHILDLESS = wp.constant(2)  # an inner node with no children (binary: child code 11 with word 0)
FAULT_TOO_DEEP = wp.constant(3)  # a node with children at depth 16
FAULT_TOO_MANY = wp.constant(4)  # more leaves than the host counted room for


@wp.func
def word_at(data: wp.array(dtype=wp.uint8), i: int) -> int:
    return int(data[i]) | (int(data[i + 1]) << 8)


@wp.func
def leaf_code(prefix: wp.int64, depth: int) -> wp.int64:
    return prefix << wp.int64(3 * (TREE_DEPTH - depth))


@wp.func
def place_leaf(
    code: wp.int64,
    depth: int,
    leaf: int,
    rows: wp.array(dtype=wp.int32),
    run_firsts: wp.array(dtype=wp.int64),
    run_blocks: wp.array(dtype=wp.int64),
    status: wp.array(dtype=wp.int64),
):
    """Give leaf number `leaf` (Morton code `code` at depth 16, node depth `depth`) its slot:
    a leaf within a block shares the slot of the leaf before it when that ended in the same
    block; otherwise it opens 8^max(13 - depth, 0) new blocks."""
    first = code >> wp.int64(9)
    span = wp.int64(1) << wp.int64(3 * wp.max(13 - depth, 0))
    total = status[STATUS_BLOCKS]
    if first == status[STATUS_LAST_BLOCK] and span == wp.int64(1):
        rows[leaf] = int(total - wp.int64(1))
        return
    rows[leaf] = int(total)
    runs = int(status[STATUS_RUNS])
    run_firsts[runs] = first
    run_blocks[runs] = span
    status[STATUS_RUNS] = wp.int64(runs + 1)
    status[STATUS_BLOCKS] = total + span
    status[STATUS_LAST_BLOCK] = first + span - wp.int64(1)


@wp.kernel
def decode_binary_tree(
    data: wp.array(dtype=wp.uint8),
    path_words: wp.array(dtype=wp.int32),
    path_codes: wp.array(dtype=wp.int64),
    path_child: wp.array(dtype=wp.int32),
    leaf_codes: wp.array(dtype=wp.int64),
    leaf_depths: wp.array(dtype=wp.int8),
    leaf_occupied: wp.array(dtype=wp.uint8),
    rows: wp.array(dtype=wp.int32),
    run_firsts: wp.array(dtype=wp.int64),
    run_blocks: wp.array(dtype=wp.int64),
    status: wp.array(dtype=wp.int64),
):
    """The leaves of a binary (.bt) stream: per inner node a little-endian 16-bit word, two
    bits per child (01 free leaf, 10 occupied leaf, 11 inner node, 00 absent); the root is an
    inner node. One thread."""
    tid = wp.tid()
    if tid != 0:
        return
    status[STATUS_LAST_BLOCK] = wp.int64(-1)
    n = data.shape[0]
    capacity = leaf_codes.shape[0]
    leaves = int(0)
    nodes = int(1)
    fault = int(0)
    where = int(0)
    pos = int(0)
    depth = int(0)
    if n < 2:
        fault = FAULT_TRUNCATED
        depth = -1
    else:
        path_words[0] = word_at(data, 0)
        path_codes[0] = wp.int64(0)
        path_child[0] = 0
        pos = 2
        if path_words[0] == 0:
            fault = FAULT_CHILDLESS
            depth = -1
    while depth >= 0:
        i = path_child[depth]
        if i == 8:
            depth -= 1
            continue
        path_child[depth] = i + 1
        bits = (path_words[depth] >> (2 * i)) & 3
        if bits == 0:
            continue
        nodes += 1
        code = (path_codes[depth] << wp.int64(3)) | wp.int64(i)
        child_depth = depth + 1
        if bits == 3:
            if child_depth == TREE_DEPTH:
                fault = FAULT_TOO_DEEP
                where = pos
                break
            if pos + 2 > n:
                fault = FAULT_TRUNCATED
                where = pos
                break
            word = word_at(data, pos)
            if word == 0:
                fault = FAULT_CHILDLESS
                where = pos
                break
            pos += 2
            depth = child_depth
            path_words[depth] = word
            path_codes[depth] = code
            path_child[depth] = 0
        else:
            if leaves >= capacity:
                fault = FAULT_TOO_MANY
                where = pos
                break
            leaf_codes[leaves] = leaf_code(code, child_depth)
            leaf_depths[leaves] = wp.int8(child_depth)
            leaf_occupied[leaves] = wp.uint8(wp.where(bits == 2, 1, 0))
            place_leaf(leaf_codes[leaves], child_depth, leaves, rows, run_firsts, run_blocks, status)
            leaves += 1
    status[STATUS_LEAVES] = wp.int64(leaves)
    status[STATUS_NODES] = wp.int64(nodes)
    status[STATUS_READ] = wp.int64(pos)
    status[STATUS_FAULT] = wp.int64(fault)
    status[STATUS_WHERE] = wp.int64(where)


@wp.kernel
def decode_full_tree(
    values: wp.array(dtype=wp.float32),
    children: wp.array(dtype=wp.uint8),
    path_masks: wp.array(dtype=wp.int32),
    path_codes: wp.array(dtype=wp.int64),
    path_child: wp.array(dtype=wp.int32),
    leaf_codes: wp.array(dtype=wp.int64),
    leaf_depths: wp.array(dtype=wp.int8),
    leaf_values: wp.array(dtype=wp.float32),
    rows: wp.array(dtype=wp.int32),
    run_firsts: wp.array(dtype=wp.int64),
    run_blocks: wp.array(dtype=wp.int64),
    status: wp.array(dtype=wp.int64),
):
    """The leaves of a full (.ot) stream: per node its float32 log-odds and a byte whose bit i
    says child i exists (records split into `values` and `children` by the host). A node
    without children is a leaf; a root without children is a leaf covering the whole tree.
    One thread."""
    tid = wp.tid()
    if tid != 0:
        return
    status[STATUS_LAST_BLOCK] = wp.int64(-1)
    n = values.shape[0]
    capacity = leaf_codes.shape[0]
    leaves = int(0)
    fault = int(0)
    where = int(0)
    index = int(0)
    depth = int(-1)
    if n == 0:
        fault = FAULT_TRUNCATED
    elif children[0] == wp.uint8(0):
        leaf_codes[0] = wp.int64(0)
        leaf_depths[0] = wp.int8(0)
        leaf_values[0] = values[0]
        place_leaf(wp.int64(0), 0, 0, rows, run_firsts, run_blocks, status)
        leaves = 1
        index = 1
    else:
        path_masks[0] = int(children[0])
        path_codes[0] = wp.int64(0)
        path_child[0] = 0
        index = 1
        depth = 0
    while depth >= 0:
        i = path_child[depth]
        if i == 8:
            depth -= 1
            continue
        path_child[depth] = i + 1
        if ((path_masks[depth] >> i) & 1) == 0:
            continue
        if index >= n:
            fault = FAULT_TRUNCATED
            where = index
            break
        mask = int(children[index])
        code = (path_codes[depth] << wp.int64(3)) | wp.int64(i)
        child_depth = depth + 1
        if mask == 0:
            if leaves >= capacity:
                fault = FAULT_TOO_MANY
                where = index
                break
            leaf_codes[leaves] = leaf_code(code, child_depth)
            leaf_depths[leaves] = wp.int8(child_depth)
            leaf_values[leaves] = values[index]
            place_leaf(leaf_codes[leaves], child_depth, leaves, rows, run_firsts, run_blocks, status)
            leaves += 1
        else:
            if child_depth == TREE_DEPTH:
                fault = FAULT_TOO_DEEP
                where = index
                break
            depth = child_depth
            path_masks[depth] = mask
            path_codes[depth] = code
            path_child[depth] = 0
        index += 1
    status[STATUS_LEAVES] = wp.int64(leaves)
    status[STATUS_NODES] = wp.int64(index)
    status[STATUS_READ] = wp.int64(index)
    status[STATUS_FAULT] = wp.int64(fault)
    status[STATUS_WHERE] = wp.int64(where)


@wp.func
def local_of_morton(m: int) -> int:
    """Block-local voxel index (hashing.index_in_block: x 64 + y 8 + z) of a 9-bit Morton code
    (bits 3j, 3j + 1, 3j + 2 are bit j of x, y, z)."""
    x = (m & 1) | ((m >> 2) & 2) | ((m >> 4) & 4)
    y = ((m >> 1) & 1) | ((m >> 3) & 2) | ((m >> 5) & 4)
    z = ((m >> 2) & 1) | ((m >> 4) & 2) | ((m >> 6) & 4)
    return (x * 8 + y) * 8 + z


@wp.kernel
def fill_leaf_voxels(
    codes: wp.array(dtype=wp.int64),
    depths: wp.array(dtype=wp.int8),
    rows: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.float32),
    log_odds: wp.array(dtype=wp.float32),
):
    """Write each leaf's value into its voxels: a leaf at depth >= 13 fills 8^(16 - depth)
    voxels of block slot rows[tid], from the voxel its Morton code names; a shallower one fills
    the 8^(13 - depth) whole blocks from slot rows[tid] on. Leaves are disjoint: so are writes."""
    tid = wp.tid()
    depth = int(depths[tid])
    value = values[tid]
    row = rows[tid]
    if depth >= 13:
        count = 1 << (3 * (TREE_DEPTH - depth))
        first = int(codes[tid] & wp.int64(511))
        for j in range(count):
            log_odds[row * 512 + local_of_morton(first + j)] = value
    else:
        blocks = 1 << (3 * (13 - depth))
        for b in range(blocks):
            base = (row + b) * 512
            for i in range(512):
                log_odds[base + i] = value
