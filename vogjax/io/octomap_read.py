"""Reading OctoMap trees: .bt and .ot files, and the data of octomap_msgs/Octomap messages.

    tree = read_octree("map.bt")                  # checked whole; nothing is built yet
    placed = leaf_blocks(tree, max_voxels=1 << 28, where="...")  # blocks, each leaf's slot

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

Pruned nodes (a leaf above depth 16) stand for all their voxels; `leaf_blocks` counts the 8x8x8
blocks a tree expands to and refuses one past the budget before allocating them, and places
each leaf in them (`kernels/octree.py` writes the voxels).
Inner nodes' values are not read: a coarse value is recomputed from the leaves (the maximum of
the children, OctoMap's `updateInnerOccupancy`), so a tree written without that update reads
the same as one written with it.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

import numpy as np
import warp as wp

from vogjax import devices
from vogjax.kernels import octree

BINARY_HEADER = "# Octomap OcTree binary file"
FULL_HEADER = "# Octomap OcTree file"
HEADER_BYTES = 1 << 16  # the header must end (its `data` line) within this many bytes
DECIMAL = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", re.ASCII)  # a header's res
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
    rows:       (L,) int32 slot of each leaf's block in a store of the tree's blocks in Morton
                order (a leaf of whole blocks: its first block's; see `leaf_blocks`)
    run_firsts, run_blocks: (R,) int64 the runs of consecutive blocks, in order: Morton code of
                the first block (voxel code >> 9) and the run's length
    """

    resolution: float
    binary: bool
    tree_type: str
    codes: np.ndarray
    depths: np.ndarray
    occupied: np.ndarray | None
    values: np.ndarray | None
    nodes: int
    rows: np.ndarray
    run_firsts: np.ndarray
    run_blocks: np.ndarray

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
    if isinstance(path, bytes):  # (octomap-python's own paths are bytes)
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a file path (str or os.PathLike), got {path!r}")
    path = Path(path)
    where = f"path {str(path)!r}"
    try:
        blob = path.read_bytes()
    except OSError as error:  # missing, a folder, no permission, a symlink loop, an I/O error
        raise ValueError(f"{where} cannot be read: {error.strerror or error}") from None
    except ValueError as error:  # a NUL byte in the name
        raise ValueError(f"{where} cannot be read: {error}") from None
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
    if not (fields["size"].isascii() and fields["size"].isdigit()) or len(fields["size"]) > 18:
        raise ValueError(f"{where} has an OctoMap header whose size {fields['size'][:30]!r} is no node count")
    return binary, fields["id"], int(fields["size"]), _resolution(fields["res"], where), position


def _resolution(text: str, where: str) -> float:
    # a plain decimal, as C++'s stream extraction reads one whole: Python's float() also takes
    # "0.1_5" (0.15, where OctoMap reads 0.1 and warns), "infinity" and full-width digits
    if not DECIMAL.fullmatch(text):
        raise ValueError(f"{where} has an OctoMap header whose res {text[:30]!r} is no number")
    return check_resolution(float(text), where)


def check_resolution(value: float, where: str) -> float:
    """A tree's resolution, checked.

    Parameters
    ----------
    value : float
        Metres.
    where : str
        The tree's source, for the error message.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Naming `where`, unless `value` is finite and within [MIN_RESOLUTION_M, MAX_RESOLUTION_M].
    """
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
        empty = [np.zeros(0, t) for t in (np.int64, np.int8, np.float32, np.int32, np.int64, np.int64)]
        return _leaves(resolution, binary, tree_type, empty, 0)
    if binary:
        return _decode_binary(data, tree_type, resolution, where, size)
    return _decode_full(data, tree_type, resolution, where, size)


def _decode_binary(data: np.ndarray, tree_type: str, resolution: float, where: str, size: int | None) -> OctreeLeaves:
    words = np.frombuffer(data[: len(data) // 2 * 2].tobytes(), dtype="<u2")
    capacity = 0  # leaf codes (01, 10) among all words: room for every leaf the tree can name
    for i in range(8):
        bits = (words >> (2 * i)) & 3
        capacity += int(np.count_nonzero((bits == 1) | (bits == 2)))
    out, status = _run(octree.decode_binary_tree, [data], capacity, wp.uint8)
    _check_status(status, len(data), "bytes", where, size)
    return _leaves(resolution, True, tree_type, out, int(status[octree.STATUS_NODES]))


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
    out, status = _run(octree.decode_full_tree, [values, children], capacity, wp.float32)
    _check_status(status, len(values), "nodes", where, size)
    return _leaves(resolution, False, tree_type, out, int(status[octree.STATUS_NODES]))


def _run(kernel, inputs: list, capacity: int, leaf_dtype) -> tuple:
    """One decode on the CPU: ([codes, depths, per-leaf field, rows, run_firsts, run_blocks] as
    NumPy arrays, status)."""
    devices.init()  # quietly: stdout carries results only
    device = "cpu"
    arrays = [wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=device, copy=False) for a in inputs]
    path = [wp.zeros(TREE_DEPTH + 1, dtype=t, device=device) for t in (wp.int32, wp.int64, wp.int32)]
    room = max(capacity, 1)
    outputs = [
        wp.empty(room, dtype=t, device=device) for t in (wp.int64, wp.int8, leaf_dtype, wp.int32, wp.int64, wp.int64)
    ]
    status = wp.zeros(octree.STATUS_SIZE, dtype=wp.int64, device=device)
    wp.launch(kernel, dim=1, inputs=[*arrays, *path], outputs=[*outputs, status], device=device)
    status = status.numpy()
    leaves, runs = int(status[octree.STATUS_LEAVES]), int(status[octree.STATUS_RUNS])
    host = [a.numpy() for a in outputs]
    return [*(a[:leaves] for a in host[:4]), *(a[:runs] for a in host[4:])], status


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


def _leaves(resolution: float, binary: bool, tree_type: str, out: list, nodes: int) -> OctreeLeaves:
    """OctreeLeaves of a decoder's outputs [codes, depths, field, rows, run_firsts, run_blocks]."""
    codes, depths, field, rows, firsts, blocks = out
    return OctreeLeaves(
        resolution,
        binary,
        tree_type,
        np.asarray(codes, np.int64),
        np.asarray(depths, np.int8),
        np.asarray(field, bool) if binary else None,
        None if binary else np.asarray(field, np.float32),
        nodes,
        np.asarray(rows, np.int32),
        np.asarray(firsts, np.int64),
        np.asarray(blocks, np.int64),
    )


# ------------------------------------------------------------------ leaves -> blocks
def block_coordinates(block_codes: np.ndarray) -> np.ndarray:
    """vogjax block coordinates of Morton block codes.

    Parameters
    ----------
    block_codes : numpy.ndarray
        (K,) int64, a voxel's Morton code (see `OctreeLeaves.codes`) shifted right by 9.

    Returns
    -------
    numpy.ndarray
        (K,3) int64 block coordinates (voxel key >> 3).
    """
    block_codes = np.asarray(block_codes, np.int64)
    out = np.zeros((len(block_codes), 3), np.int64)
    for j in range(BLOCK_DEPTH):
        for a in range(3):
            out[:, a] |= ((block_codes >> (3 * j + a)) & 1) << j
    return out - KEY_OFFSET // 8


def count_blocks(tree: OctreeLeaves) -> int:
    """The 8x8x8 blocks a tree's leaves fill, counted without expanding them.

    Parameters
    ----------
    tree : OctreeLeaves

    Returns
    -------
    int
    """
    return int(tree.run_blocks.sum())


def leaf_blocks(tree: OctreeLeaves, max_voxels: int, where: str) -> np.ndarray:
    """The coordinates (K,3) int64 (voxel key >> 3) of the blocks a tree's leaves fill, in the
    order of the slots `tree.rows` names, every pruned leaf standing for its voxels; checked
    against the budget before anything of their number is made.

    Parameters
    ----------
    tree : OctreeLeaves
        A decoded tree.
    max_voxels : int
        Budget: the voxel slots of the blocks (512 a block) may not exceed it.
    where : str
        The tree's source, for the error message.

    Raises
    ------
    ValueError
        When the tree would take more than `max_voxels` voxel slots.
    """
    total = count_blocks(tree)
    if 512 * total > max_voxels or total >= 1 << 31:
        raise ValueError(
            f"{where} expands to {tree.voxel_count()} voxels in {total} blocks of 512 ({512 * total} voxel "
            f"slots), more than max_voxels={max_voxels}; pass a larger max_voxels to read it"
        )
    counts = tree.run_blocks
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return block_coordinates(np.repeat(tree.run_firsts, counts) + offsets)
