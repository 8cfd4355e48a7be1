"""OctoMap files (.bt, .ot) written in NumPy, in OctoMap's own layout, for octovis, rviz and
any program linked against OctoMap (`octomap::OcTree`, `AbstractOcTree::read`).

    vogjax.io.octomap.save(global_map, "map.bt")     # or "map.ot", or a VoxelSet
    octomap.OcTree(b"map.bt"); octomap.OcTree.read(b"map.ot")   # octomap-python reads them

The tree is OctoMap's: depth 16, voxel k on an axis has key k + 32768 (so every coordinate must
lie within +-32768 voxel sizes of the origin), the child of a node at depth d that holds key
(x, y, z) is x_b + 2 y_b + 4 z_b with b = 15 - d the key bit, nodes written depth first,
children in that order. Eight children that are all leaves with equal values collapse into
their parent (OctoMap's pruning); an inner node holds the largest of its children's log-odds.

- .bt ("binary", max-likelihood): per inner node two bytes, two bits per child in the
  little-endian 16-bit word: bit 2i alone for a free leaf, bit 2i+1 alone for an occupied leaf,
  both for an inner node, neither for an absent child. Occupied and free follow the map's own
  thresholds; observed voxels the map calls unknown (probability between free_threshold and
  occupied_threshold) are left out, so OctoMap reports them unknown too. OctoMap gives the
  leaves it reads its clamping bounds as log-odds.
- .ot (full): per node its float32 log-odds and one byte of child-exists bits, every voxel's
  log-odds as the map holds it.

The header carries the voxel size at full precision and the node count OctoMap checks.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from vogjax.io.atomic import AtomicPath
from vogjax.io.voxels import VoxelSet

TREE_DEPTH = 16
KEY_OFFSET = 1 << 15  # OctoMap's tree_max_val: key = floor(x / s) + 32768
FORMATS = ("bt", "ot")
_BINARY_HEADER = "# Octomap OcTree binary file"
_FULL_HEADER = "# Octomap OcTree file"
# two-bit child codes of the binary format
_FREE, _OCCUPIED, _INNER = 0b01, 0b10, 0b11


@dataclasses.dataclass(frozen=True)
class Tree:
    """A pruned octree in depth-first order (root first), one row per node.

    level:    (N,) int8, 0 for the root, 16 for a single voxel
    code:     (N,) int64, the node's Morton prefix (3 bits per level, z y x from high to low)
    value:    (N,) float32, log-odds (leaves: the voxel's; inner nodes: max of the children)
    leaf:     (N,) bool
    children: (N,) uint8, bit i set when child i exists
    binary:   (N,) uint16, the .bt word of each node (two bits per child; a leaf child counts
              as occupied at log-odds >= 0, OctoMap's default threshold)
    """

    level: np.ndarray
    code: np.ndarray
    value: np.ndarray
    leaf: np.ndarray
    children: np.ndarray
    binary: np.ndarray

    def __len__(self) -> int:
        return len(self.level)


def save(source, path, format: str | None = None) -> int:
    """Write `source` (a VoxelMap, GlobalMap, ConfidenceMap or VoxelSet) to `path` as .bt or .ot (`format`,
    default: the file's suffix). Returns the number of octree nodes written."""
    path = Path(path)
    format = format or path.suffix.lstrip(".").lower()
    if format not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    voxels = source if isinstance(source, VoxelSet) else VoxelSet.from_map(source)
    try:
        data, nodes = _encode_bt(voxels) if format == "bt" else _encode_ot(voxels)
    except ValueError as error:  # say what was being written
        raise ValueError(f"source, written to {str(path)!r}: {error}") from None
    with AtomicPath(path) as temporary:
        temporary.write_bytes(data)
    return nodes


def save_bt(source, path) -> int:
    return save(source, path, "bt")


def save_ot(source, path) -> int:
    return save(source, path, "ot")


def octomap_keys(voxels: VoxelSet) -> np.ndarray:
    """(K,3) int64 OctoMap keys of the voxels; ValueError for voxels the 16-bit keys cannot hold."""
    keys = voxels.keys() + KEY_OFFSET
    if len(keys) and (keys.min() < 0 or keys.max() >= 2 * KEY_OFFSET):
        limit = KEY_OFFSET * voxels.voxel_size
        raise ValueError(
            f"centres reach {np.abs(voxels.centres).max():.6g} m from the origin: OctoMap's 16-bit keys "
            f"hold coordinates in [-{limit:.6g}, {limit:.6g}) m at voxel size {voxels.voxel_size} m"
        )
    return keys


def encode_bt(voxels: VoxelSet) -> bytes:
    """The bytes of a .bt file: max-likelihood occupancy, unknown voxels left out."""
    return _encode_bt(voxels)[0]


def encode_ot(voxels: VoxelSet) -> bytes:
    """The bytes of a .ot file: every observed voxel's log-odds."""
    return _encode_ot(voxels)[0]


def _encode_bt(voxels: VoxelSet) -> tuple[bytes, int]:
    state = voxels.state()
    known = state != 0
    # max-likelihood values: OctoMap's clamping bounds stand for free and occupied; only their
    # order matters for pruning and the inner nodes' max
    values = np.where(state[known] == 2, np.float32(1.0), np.float32(-1.0))
    tree = build_tree(octomap_keys(voxels)[known], values)
    inner = ~tree.leaf
    body = tree.binary[inner].astype("<u2").tobytes()
    return _header(_BINARY_HEADER, len(tree), voxels.voxel_size) + body, len(tree)


def _encode_ot(voxels: VoxelSet) -> tuple[bytes, int]:
    tree = build_tree(octomap_keys(voxels), voxels.log_odds)
    records = np.zeros(len(tree), dtype=[("value", "<f4"), ("children", "u1")])
    records["value"] = tree.value
    records["children"] = tree.children
    return _header(_FULL_HEADER, len(tree), voxels.voxel_size) + records.tobytes(), len(tree)


def build_tree(keys: np.ndarray, values: np.ndarray) -> Tree:
    """The pruned octree of voxels with OctoMap keys (K,3) in [0, 65536) and float32 values."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    values = np.asarray(values, dtype=np.float32)
    if len(keys) == 0:
        empty = np.zeros(0)
        return Tree(
            empty.astype(np.int8),
            empty.astype(np.int64),
            empty.astype(np.float32),
            empty.astype(bool),
            empty.astype(np.uint8),
            empty.astype(np.uint16),
        )
    code = morton(keys)
    order = np.argsort(code, kind="stable")
    code, value = code[order], values[order]
    if np.any(np.diff(code) == 0):
        raise ValueError("keys must name each voxel once")
    leaf = np.ones(len(code), dtype=bool)
    levels = []  # per level, bottom up: (code, value, leaf, children, binary)
    empty_children = np.zeros(len(code), dtype=np.uint8)
    children = empty_children
    binary = empty_children.astype(np.uint16)
    for level in range(TREE_DEPTH, 0, -1):
        # group this level's nodes (sorted by code) under their parents
        parent = code >> 3
        starts = np.flatnonzero(np.r_[True, parent[1:] != parent[:-1]])
        counts = np.diff(np.r_[starts, len(code)])
        index = (code & 7).astype(np.uint8)
        top = np.maximum.reduceat(value, starts)
        # eight leaves with one value collapse into their parent (never into the root)
        collapse = (
            (counts == 8)
            & np.logical_and.reduceat(leaf, starts)
            & (np.minimum.reduceat(value, starts) == top)
            & (level > 1)
        )
        keep = ~np.repeat(collapse, counts)
        levels.append((level, code[keep], value[keep], leaf[keep], children[keep], binary[keep]))
        bits = np.where(leaf, np.where(value >= 0, _OCCUPIED, _FREE), _INNER).astype(np.uint16)
        parent_children = np.bitwise_or.reduceat((1 << index.astype(np.uint16)).astype(np.uint8), starts)
        parent_binary = np.bitwise_or.reduceat(bits << (2 * index.astype(np.uint16)), starts)
        code, value, leaf = parent[starts], top, collapse
        children = np.where(collapse, 0, parent_children).astype(np.uint8)
        binary = np.where(collapse, 0, parent_binary).astype(np.uint16)
    levels.append((0, code, value, leaf, children, binary))  # the root
    level = np.concatenate([np.full(len(c), lv, dtype=np.int8) for lv, c, *_ in levels])
    fields = [np.concatenate([part[i] for part in levels]) for i in range(1, 6)]
    # depth first: a node's prefix padded to full depth, ancestors before descendants
    position = fields[0] << (3 * (TREE_DEPTH - level.astype(np.int64)))
    order = np.lexsort((level, position))
    return Tree(level[order], *(f[order] for f in fields))


def morton(keys: np.ndarray) -> np.ndarray:
    """(K,) int64 interleaved keys: bit b of x, y, z at bits 3b, 3b+1, 3b+2."""
    keys = np.asarray(keys, dtype=np.int64)
    code = np.zeros(len(keys), dtype=np.int64)
    for bit in range(TREE_DEPTH):
        for axis in range(3):
            code |= ((keys[:, axis] >> bit) & 1) << (3 * bit + axis)
    return code


def _header(first_line: str, nodes: int, voxel_size: float) -> bytes:
    return (f"{first_line}\n# written by vogjax\n#\nid OcTree\nsize {nodes}\nres {voxel_size!r}\ndata\n").encode()
