"""Reading OctoMap trees: .bt and .ot files, and the data of octomap_msgs/Octomap messages.

    tree = read_octree("map.bt")                  # checked whole; nothing is built yet
    blocks, values = octree_blocks(tree, leaf_values, max_voxels=1 << 28, where="...")

`vj.VoxelMap.from_octomap(path)` is the front door; this module does the reading and checking.
Every fault is a one-line ValueError naming its source, raised before any map is built:

- header: the first line is OctoMap's ("# Octomap OcTree binary file" for .bt, "# Octomap
  OcTree file" for .ot), then `id`, `size` and `res` lines (comments and unknown keywords
  skipped, as OctoMap skips them) up to a `data` line, within HEADER_BYTES;
- node type: a full stream must hold an `OcTree` (float log-odds per node); other node types
  (ColorOcTree, OcTreeStamped, CountingOcTree, ...) are refused by name. A binary stream holds
  occupancy only, the same for every occupancy tree, so OcTree, ColorOcTree and OcTreeStamped
  are read (their colours and stamps are not in it);
- resolution: finite, within MapConfig's voxel sizes [1e-4, 1e3] m;
- data: it ends inside the tree (truncated), holds bytes after it, an inner node without
  children, a node with children at depth 16, a NaN or infinite log-odds, or a node count other
  than the header's `size`.

Pruned nodes (a leaf above depth 16) stand for all their voxels; `octree_blocks` counts the
voxels and 8x8x8 blocks a tree expands to and refuses one past the budget before allocating.
Inner nodes' values are not read: a coarse value is recomputed from the leaves (the maximum of
the children, OctoMap's `updateInnerOccupancy`), so a tree written without that update reads
the same as one written with it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import warp as wp

from vogjax.kernels import octree

BINARY_HEADER = "# Octomap OcTree binary file"
FULL_HEADER = "# Octomap OcTree file"
HEADER_BYTES = 1 << 16  # the header must end (its `data` line) within this many bytes
BINARY_TYPES = ("OcTree", "ColorOcTree", "OcTreeStamped")
FULL_TYPES = ("OcTree",)
MIN_RESOLUTION_M, MAX_RESOLUTION_M = 1e-4, 1e3  # MapConfig.voxel_size's range
TREE_DEPTH = 16
BLOCK_DEPTH = TREE_DEPTH - 3  # a node at this depth is one 8x8x8 block
KEY_OFFSET = 1 << 15  # OctoMap's key of voxel k is k + 32768
_FULL_RECORD = np.dtype([("value", "<f4"), ("children", "u1")])
_FAULTS = {
    1: "ends inside the tree (truncated)",
    2: "has an inner node without children (inconsistent child bits)",
    3: "has a node with children at depth 16, below OctoMap's deepest level (inconsistent child bits)",
    4: "has more leaves than its child bits name",
}


@dataclasses.dataclass(frozen=True)
class OctreeLeaves:
    """The leaves of a decoded OctoMap tree, sorted by Morton code.

    resolution: voxel edge of the tree's leaves at depth 16, metres
    binary:     True for a binary (.bt) tree: `occupied` holds the leaves' states and `values`
                is None; False for a full (.ot) tree: `values` holds their log-odds
    tree_type:  the header's or message's `id` ("OcTree", ...)
    codes:      (L,) int64 Morton code of each leaf's first voxel at depth 16 (bit 3b + a is bit
                b of the OctoMap key on axis a)
    depths:     (L,) int8 depth of each leaf, 16 for one voxel, d for 8^(16-d) voxels
    occupied:   (L,) bool (binary trees) or None
    values:     (L,) float32 finite log-odds (full trees) or None
    nodes:      nodes of the tree, inner ones included
    """

    resolution: float
    binary: bool
    tree_type: str
    codes: np.ndarray
    depths: np.ndarray
    occupied: np.ndarray | None
    values: np.ndarray | None
    nodes: int

    def __len__(self) -> int:
        return len(self.codes)

    def voxel_count(self) -> int:
        """Voxels the leaves stand for (a pruned leaf at depth d for 8^(16-d))."""
        return int(np.sum(np.left_shift(1, 3 * (TREE_DEPTH - self.depths.astype(np.int64)))))


def read_octree(path) -> OctreeLeaves:
    """The leaves of the OctoMap file at `path` (.bt or .ot, told by its first line), checked whole.

    Parameters
    ----------
    path : str or os.PathLike
        An OctoMap file written by OctoMap (`writeBinary`, `write`), octomap_server or vogjax.

    Returns
    -------
    OctreeLeaves
        The tree's leaves and resolution.

    Raises
    ------
    ValueError
        One line naming the file, for a file that cannot be read or is no well-formed OctoMap
        OcTree (see the module's list of checks).
    """
    path = Path(path)
    where = f"path {str(path)!r}"
    try:
        blob = path.read_bytes()
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as error:
        raise ValueError(f"{where} cannot be read: {error.strerror or error}") from None
    binary, tree_type, size, resolution, offset = read_header(blob, where)
    data = np.frombuffer(blob, dtype=np.uint8, offset=offset)
    return decode(data, binary, tree_type, resolution, where, size)


def read_header(blob: bytes, where: str) -> tuple[bool, str, int, float, int]:
    """(binary, id, size, res, offset of the data) of an OctoMap file's bytes.

    Parameters
    ----------
    blob : bytes
        The file's bytes (only the first HEADER_BYTES are searched for the header).
    where : str
        What the bytes are, for error messages ("path 'map.bt'").

    Raises
    ------
    ValueError
        When the first line is no OctoMap header, the header misses `id`, `size`, `res` or
        `data`, or holds a bad value.
    """
    head = blob[:HEADER_BYTES]
    end = head.find(b"\n")
    first = head[: end if end >= 0 else len(head)].decode("latin-1").rstrip("\r")
    if first.startswith(BINARY_HEADER):
        binary = True
    elif first.startswith(FULL_HEADER):
        binary = False
    else:
        shown = first[:60] + ("..." if len(first) > 60 else "")
        raise ValueError(
            f"{where} is no OctoMap file: its first line is {shown!r}, not {BINARY_HEADER!r} (.bt) "
            f"or {FULL_HEADER!r} (.ot)"
        )
    fields: dict[str, str] = {}
    position = end + 1 if end >= 0 else len(head)
    while True:
        end = head.find(b"\n", position)
        if end < 0:
            raise ValueError(
                f"{where} has no complete OctoMap header (no 'data' line in its first {HEADER_BYTES} bytes)"
            )
        tokens = head[position:end].decode("latin-1").split()
        position = end + 1
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0] == "data":
            break
        if tokens[0] in ("id", "size", "res"):
            if len(tokens) != 2 or tokens[0] in fields:
                raise ValueError(f"{where} has a malformed OctoMap header line {' '.join(tokens)[:60]!r}")
            fields[tokens[0]] = tokens[1]
    missing = [name for name in ("id", "size", "res") if name not in fields]
    if missing:
        raise ValueError(f"{where} has an OctoMap header without {', '.join(missing)}")
    if not fields["size"].isdigit() or len(fields["size"]) > 18:
        raise ValueError(f"{where} has an OctoMap header whose size {fields['size'][:30]!r} is no node count")
    return binary, fields["id"], int(fields["size"]), _resolution(fields["res"], where), position


def _resolution(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where} has an OctoMap header whose res {text[:30]!r} is no number") from None
    return check_resolution(value, where)


def check_resolution(value: float, where: str) -> float:
    """`value` as a voxel size in [MIN_RESOLUTION_M, MAX_RESOLUTION_M]; ValueError naming `where`."""
    if not (math.isfinite(value) and MIN_RESOLUTION_M <= value <= MAX_RESOLUTION_M):
        raise ValueError(
            f"{where} has resolution {value!r} m; vogjax reads trees of {MIN_RESOLUTION_M:g} to {MAX_RESOLUTION_M:g} m"
        )
    return float(value)


def decode(
    data: np.ndarray, binary: bool, tree_type: str, resolution: float, where: str, size: int | None = None
) -> OctreeLeaves:
    """The leaves of a tree's serialised nodes (a file's data, or a message's `data`).

    Parameters
    ----------
    data : numpy.ndarray
        (B,) uint8, the nodes as OctoMap writes them (`writeBinaryData` or `writeData`).
    binary : bool
        Whether the stream is binary (.bt) or full (.ot).
    tree_type : str
        The tree's `id`; checked against BINARY_TYPES or FULL_TYPES.
    resolution : float
        Leaf voxel size, metres (checked).
    where : str
        The source, for error messages.
    size : int or None
        The node count the stream must hold (a file header's `size`); None: any (messages).

    Raises
    ------
    ValueError
        One line naming `where`, for any fault of the stream.
    """
    resolution = check_resolution(float(resolution), where)
    allowed = BINARY_TYPES if binary else FULL_TYPES
    if tree_type not in allowed:
        kind = "binary (.bt)" if binary else "full (.ot)"
        raise ValueError(
            f"{where} holds a {kind} {tree_type[:40]!r} tree; vogjax reads {kind} trees of {', '.join(allowed)} only"
        )
    data = np.ascontiguousarray(data, dtype=np.uint8).reshape(-1)
    if size == 0 or (size is None and len(data) == 0):
        if len(data):
            raise ValueError(f"{where} holds {len(data)} bytes of data after a tree of size 0")
        return _leaves(resolution, binary, tree_type, np.zeros(0, np.int64), np.zeros(0, np.int8), np.zeros(0), 0)
    if binary:
        return _decode_binary(data, tree_type, resolution, where, size)
    return _decode_full(data, tree_type, resolution, where, size)


def _decode_binary(data: np.ndarray, tree_type: str, resolution: float, where: str, size: int | None) -> OctreeLeaves:
    words = np.frombuffer(data[: len(data) // 2 * 2].tobytes(), dtype="<u2")
    capacity = 0  # leaf codes (01, 10) among all words: room for every leaf the tree can name
    for i in range(8):
        bits = (words >> (2 * i)) & 3
        capacity += int(np.count_nonzero((bits == 1) | (bits == 2)))
    codes, depths, occupied, status = _run(octree.decode_binary_tree, [data], capacity, wp.uint8, path_dtype=wp.int32)
    _check_status(status, len(data), "bytes", where, size)
    return _leaves(resolution, True, tree_type, codes, depths, occupied.astype(bool), int(status[octree.STATUS_NODES]))


def _decode_full(data: np.ndarray, tree_type: str, resolution: float, where: str, size: int | None) -> OctreeLeaves:
    record = _FULL_RECORD.itemsize
    if size is not None and len(data) < size * record:
        raise ValueError(
            f"{where} is truncated: its header's size {size} needs {size * record} bytes of nodes, it holds {len(data)}"
        )
    if len(data) % record:
        raise ValueError(f"{where} holds {len(data)} bytes of nodes, no whole number of {record}-byte nodes")
    records = data.view(_FULL_RECORD)
    values = np.ascontiguousarray(records["value"])
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        raise ValueError(f"{where} holds a NaN or infinite log-odds ({values[bad[0]]}) in node {int(bad[0])}")
    children = np.ascontiguousarray(records["children"])
    capacity = int(np.count_nonzero(children == 0))
    codes, depths, leaf_values, status = _run(
        octree.decode_full_tree, [values, children], capacity, wp.float32, path_dtype=wp.int32
    )
    _check_status(status, len(values), "nodes", where, size)
    return _leaves(resolution, False, tree_type, codes, depths, leaf_values, int(status[octree.STATUS_NODES]))


def _run(kernel, inputs: list, capacity: int, leaf_dtype, path_dtype) -> tuple:
    """One decode on the CPU: (codes, depths, per-leaf field, status) as NumPy arrays."""
    device = "cpu"
    arrays = [wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=device, copy=False) for a in inputs]
    path = [
        wp.zeros(TREE_DEPTH + 1, dtype=path_dtype, device=device),
        wp.zeros(TREE_DEPTH + 1, dtype=wp.int64, device=device),
        wp.zeros(TREE_DEPTH + 1, dtype=wp.int32, device=device),
    ]
    room = max(capacity, 1)
    codes = wp.empty(room, dtype=wp.int64, device=device)
    depths = wp.empty(room, dtype=wp.int8, device=device)
    field = wp.empty(room, dtype=leaf_dtype, device=device)
    status = wp.zeros(5, dtype=wp.int64, device=device)
    wp.launch(kernel, dim=1, inputs=[*arrays, *path], outputs=[codes, depths, field, status], device=device)
    status = status.numpy()
    count = int(status[octree.STATUS_LEAVES])
    return codes.numpy()[:count], depths.numpy()[:count], field.numpy()[:count], status


def _check_status(status: np.ndarray, length: int, unit: str, where: str, size: int | None) -> None:
    fault = int(status[octree.STATUS_FAULT])
    if fault:
        at = int(status[octree.STATUS_WHERE])
        raise ValueError(f"{where} {_FAULTS[fault]} (at {'byte' if unit == 'bytes' else 'node'} {at} of the data)")
    read, nodes = int(status[octree.STATUS_READ]), int(status[octree.STATUS_NODES])
    if read != length:
        raise ValueError(f"{where} holds {length - read} {unit} of data after its tree")
    if size is not None and nodes != size:
        raise ValueError(f"{where} holds a tree of {nodes} nodes; its header's size says {size}")


def _leaves(resolution, binary, tree_type, codes, depths, field, nodes) -> OctreeLeaves:
    return OctreeLeaves(
        resolution,
        binary,
        tree_type,
        np.asarray(codes, np.int64),
        np.asarray(depths, np.int8),
        np.asarray(field, bool) if binary else None,
        None if binary else np.asarray(field, np.float32),
        nodes,
    )


# ------------------------------------------------------------------ leaves -> blocks
def _local_index_table() -> np.ndarray:
    """(512,) the block-local voxel index (x 64 + y 8 + z, hashing.index_in_block) of each
    9-bit Morton code within a block."""
    m = np.arange(512)
    axes = [sum(((m >> (3 * j + a)) & 1) << j for j in range(3)) for a in range(3)]
    return (axes[0] * 64 + axes[1] * 8 + axes[2]).astype(np.int64)


_LOCAL = _local_index_table()


def block_coordinates(block_codes: np.ndarray) -> np.ndarray:
    """(K,3) int64 vogjax block coordinates of Morton block codes (a voxel code >> 9)."""
    block_codes = np.asarray(block_codes, np.int64)
    out = np.zeros((len(block_codes), 3), np.int64)
    for j in range(BLOCK_DEPTH):
        for a in range(3):
            out[:, a] |= ((block_codes >> (3 * j + a)) & 1) << j
    return out - KEY_OFFSET // 8


def count_blocks(tree: OctreeLeaves) -> int:
    """8x8x8 blocks the tree's leaves fill (without expanding them)."""
    depths = tree.depths.astype(np.int64)
    big = depths <= BLOCK_DEPTH
    small_blocks = tree.codes[~big] >> 9  # sorted: leaves come in Morton order
    distinct = int(len(small_blocks) and 1 + np.count_nonzero(small_blocks[1:] != small_blocks[:-1]))
    return distinct + int(np.sum(np.left_shift(1, 3 * (BLOCK_DEPTH - depths[big]))))


def octree_blocks(tree: OctreeLeaves, leaf_values: np.ndarray, max_voxels: int, where: str):
    """The tree's voxels as vogjax blocks: block coordinates (K,3) int64 (voxel key >> 3) and
    log-odds (K,512) float32 (NaN where no leaf is), every pruned leaf expanded to its voxels.

    Parameters
    ----------
    tree : OctreeLeaves
        A decoded tree.
    leaf_values : numpy.ndarray
        (L,) float32, the log-odds each leaf's voxels get.
    max_voxels : int
        Budget: the voxel slots the blocks take (512 a block) may not exceed it.
    where : str
        The tree's source, for the error message.

    Raises
    ------
    ValueError
        When the tree would take more than `max_voxels` voxel slots (checked before allocating).
    """
    blocks = count_blocks(tree)
    if blocks * 512 > max_voxels:
        raise ValueError(
            f"{where} expands to {tree.voxel_count()} voxels in {blocks} blocks of 512 ({blocks * 512} voxel "
            f"slots), more than max_voxels={max_voxels}; pass a larger max_voxels to read it"
        )
    depths = tree.depths.astype(np.int64)
    values = np.asarray(leaf_values, np.float32)
    big = depths <= BLOCK_DEPTH
    # leaves within a block: each voxel's Morton code (a pruned leaf's are consecutive)
    codes, small_depths, small_values = tree.codes[~big], depths[~big], values[~big]
    if np.any(small_depths != TREE_DEPTH):
        counts = np.left_shift(1, 3 * (TREE_DEPTH - small_depths))
        firsts = np.cumsum(counts) - counts
        codes = np.repeat(codes, counts) + (np.arange(int(counts.sum())) - np.repeat(firsts, counts))
        small_values = np.repeat(small_values, counts)
    voxel_blocks = codes >> 9
    new_block = np.r_[True, voxel_blocks[1:] != voxel_blocks[:-1]] if len(codes) else np.zeros(0, bool)
    small_rows = np.cumsum(new_block) - 1
    small_ids = voxel_blocks[new_block]
    # leaves of whole blocks: each block once, filled
    per_leaf = np.left_shift(1, 3 * (BLOCK_DEPTH - depths[big]))
    firsts = np.cumsum(per_leaf) - per_leaf
    big_ids = np.repeat(tree.codes[big] >> 9, per_leaf) + (np.arange(int(per_leaf.sum())) - np.repeat(firsts, per_leaf))
    ids = np.concatenate([small_ids, big_ids])
    out = np.full((len(ids), 512), np.nan, np.float32)
    out.reshape(-1)[small_rows * 512 + _LOCAL[codes & 511]] = small_values
    out[len(small_ids) :] = np.repeat(values[big], per_leaf)[:, None]
    return block_coordinates(ids), out
