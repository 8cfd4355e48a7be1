"""The coarse levels a block map keeps beside its level-0 blocks (`kernels/levels.py`).

Level k (1 <= k <= MAX_LEVEL) is a BlockStore of its own, of voxels 2^k times the map's edge,
each holding the maximum log-odds of its observed level-0 voxels (NaN: none observed), so the
queries of level 0 run on it unchanged with the voxel size scaled by 2^k. A map builds a level
the first time it is queried and from then on keeps every level it built current.

Keeping them current: each write notes the level-0 blocks it wrote (`note`: their keys and,
from integration, a mask of the 2x2x2 cells of each whose voxels changed), and the next coarse
query first recomputes what those blocks decide in every kept level (`flush`; levels 1-3 only
above the changed cells, reading the values above the others), so a query always sees every
write before it, and the scans integrated between two queries share one recomputation. A log
grown past FLUSH_KEYS keys is flushed by the write itself. A coarse block with no observed
voxel left is released, so a level holds the blocks a fresh build would, whatever happened
before.

Three levels at a time: a block decides the voxels above it in the next three levels alone
(`kernels/levels.py`), so levels 1-3 are one launch over the noted blocks, levels 4-6 one over
the level-3 blocks whose voxels changed, and so on: an update after every scan pays one launch
for the planner's levels 1-3, where a level at a time paid three and their host work (a scan
writes a few dozen blocks, where a launch's fixed cost outweighs the kernel). A group passes up
only the blocks whose top voxel changed, so once nothing changed the groups above are left as
they are, launches and all. Parent blocks are allocated when the kernel finds them missing (it
flags the block and writes nothing; the host allocates and fills it again), so an update that
reaches no new coarse block searches for none.

Measured in benchmarks/bench_octomap.py (docs/benchmarks/octomap.md).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.kernels import levels
from vogjax.maps import parallel
from vogjax.maps.blocks import EMPTY_KEY, BlockStore
from vogjax.maps.replay import Replay

# OctoMap's depth 16 - k: level 15 is depth 1, the root's children. (The root, level 16, is not
# aligned with vogjax's keys: OctoMap's keys are offset by 2^15.)
MAX_LEVEL = 15
LAYERS = {"log_odds": (wp.float32, np.nan)}
# Noted block keys a map holds before a write recomputes its levels itself (8 MiB of keys).
FLUSH_KEYS = 1 << 20
ALL_CELLS = np.uint64(0xFFFF_FFFF_FFFF_FFFF)  # a block's cell mask when any of its 64 cells may have changed


def check_level(level: int) -> int:
    """A query's level, checked.

    Parameters
    ----------
    level : int
        0 (the map's voxels) to MAX_LEVEL.

    Returns
    -------
    int
        The level, as a Python int.

    Raises
    ------
    ValueError
        Naming `level`, when it is no integer (a bool is not one) in [0, MAX_LEVEL].
    """
    if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, np.integer)) or not 0 <= level <= MAX_LEVEL:
        raise ValueError(
            f"level must be an integer in [0, {MAX_LEVEL}] (voxels of voxel_size * 2^level), got {level!r}"
        )
    return int(level)


def level_scales(voxel_size: float, level: int) -> tuple[np.float64, np.float64]:
    """The voxel edge of a level and its inverse, as the kernels take them.

    Both are level 0's times an exact power of two (`voxel_size * 2^level` and
    `(1 / voxel_size) * 2^-level`), so a point's coarse key is its level-0 key shifted right by
    `level`, bit for bit.

    Parameters
    ----------
    voxel_size : float
        Level 0's voxel edge, metres.
    level : int
        The level.

    Returns
    -------
    resolution : numpy.float64
        The level's voxel edge, metres.
    inv_resolution : numpy.float64
        Its inverse, 1/m.
    """
    return np.float64(np.ldexp(voxel_size, level)), np.float64(np.ldexp(1.0 / voxel_size, -level))


def shift_keys(keys: np.ndarray, levels: int) -> np.ndarray:
    """Packed keys (K,) of the blocks `levels` levels up from packed block keys `keys` (repeats
    kept), computed on the packed fields: a biased coordinate f = c + 2^20 becomes
    (c >> levels) + 2^20 = (f >> levels) + 2^20 - 2^(20 - levels), which fits its 21 bits, so
    all three fields shift in one word with no carry between them."""
    if levels == 0:
        return keys
    low = (1 << (21 - levels)) - 1  # what is left of a field shifted right
    offset = (1 << 20) - (1 << (20 - levels))
    mask = np.int64((low << 42) | (low << 21) | low)
    return ((keys >> levels) & mask) + np.int64((offset << 42) | (offset << 21) | offset)


class Levels:
    """The coarse levels 1..count of one map, on its device.

    releases: whether a level-0 voxel can go back to unobserved (a GlobalMap's can; a
    VoxelMap's cannot), so that coarse blocks may empty and must be checked for release.
    """

    def __init__(self, device, releases: bool = True):
        self.device = device
        self.releases = releases
        self.stores: list[BlockStore] = []
        self._noted: list[tuple[np.ndarray, np.ndarray | None]] = []  # (keys, cells) per note
        self._noted_keys = 0
        self._noted_distinct = False  # the one array noted is vouched distinct (`note`)
        self._launches: dict = {}  # group's first level -> its replayed launch and buffers (_recorded_fill)
        self._updating = False  # extend is under way (`stale`)

    @property
    def count(self) -> int:
        """The coarsest level kept (0: none)."""
        return len(self.stores)

    @property
    def stale(self) -> bool:
        """Whether writes were noted that the levels do not show yet, or the levels are being
        brought up to date (a reader then waits for that, rather than reading a level part-way)."""
        return bool(self._noted) or self._updating

    def store(self, level: int) -> BlockStore:
        return self.stores[level - 1]

    def memory_bytes(self) -> int:
        return sum(store.memory_bytes() for store in self.stores)

    def extend(self, base: BlockStore, level: int) -> None:
        """Bring the levels up to date, then build levels count+1 .. `level` from scratch (up
        to three from the level below)."""
        self._updating = True
        try:
            self._extend(base, level)
        finally:
            self._updating = False

    def _extend(self, base: BlockStore, level: int) -> None:
        self.flush(base)
        while self.count < level:
            start = self.count
            below = self.stores[-1] if self.stores else base
            depth = min(3, level - start)
            self.stores += [BlockStore(self.device, LAYERS) for _ in range(depth)]
            keys = _live_keys(below)
            for i in range(1, depth + 1):  # every block needs its parents: allocated up front
                self._allocate(start + i, shift_keys(keys, i))
            self._fill(start, depth, below, keys)

    def rebuild(self, base: BlockStore) -> None:
        """Every kept level from scratch (after the level-0 store was replaced)."""
        count = self.count
        self.stores, self._launches = [], {}
        self._noted, self._noted_keys, self._noted_distinct = [], 0, False
        self.extend(base, count)

    def note(self, base: BlockStore, keys: np.ndarray, cells: np.ndarray | None = None, distinct: bool = False) -> None:
        """Record that the level-0 blocks with packed keys `keys` (any order, repeats allowed,
        released blocks included) were written; recomputed at the next `flush`. `cells` (K,)
        uint64: per block, the 2x2x2 cells whose voxels changed (`kernels/levels.py`); None:
        any of them. `distinct`: the caller vouches that `keys` holds no repeats and no
        EMPTY_KEY (one integration pass's blocks), so a flush of these keys alone need not
        sort them. The arrays are kept, not copied: the caller gives them up."""
        if not self.stores or len(keys) == 0:
            return
        self._noted.append((np.asarray(keys, np.int64), None if cells is None else np.asarray(cells, np.uint64)))
        self._noted_distinct = distinct and len(self._noted) == 1
        self._noted_keys += len(keys)
        if self._noted_keys > FLUSH_KEYS:
            self.flush(base)

    def flush(self, base: BlockStore) -> None:
        """Recompute, in every kept level, what the blocks noted since decide."""
        if not self._noted:
            return
        if self._noted_distinct:  # in any order: each block writes voxels no other block does
            changed, cells = self._noted[0]
        else:
            changed, cells = _merge_noted(self._noted)
        self._noted, self._noted_keys, self._noted_distinct = [], 0, False
        level, below = 0, base
        while level < self.count and len(changed):
            depth = min(3, self.count - level)
            changed = self._fill(level, depth, below, changed, cells)
            cells = None  # a group above recomputes whole blocks
            level += depth
            below = self.store(level)

    def _fill(
        self, level: int, depth: int, below: BlockStore, keys: np.ndarray, cells: np.ndarray | None = None
    ) -> np.ndarray:
        """Recompute, in levels level+1 .. level+depth, the voxels that the blocks `keys`
        (distinct) of `below` (level `level`) decide, above their `cells` (`note`; None: all);
        release coarse blocks left empty. Returns the distinct keys of the level-(level+depth)
        blocks whose voxels changed."""
        if len(keys) == 0:
            return keys
        stores = [self.store(level + i) for i in range(1, depth + 1)]
        flags = self._launch_fill(level, depth, below, stores, keys, cells)
        # A block whose parents are not all there yet is flagged and left unwritten: its missing
        # parents are allocated and it is filled again. Most updates allocate nothing (the scan
        # mapped no new coarse block), and they pay no search for parents at all.
        missing = flags < 0
        if missing.any():
            absent = keys[missing]
            levels_missing = int(np.bitwise_or.reduce(-1 - flags[missing]))
            for i in range(1, depth + 1):
                if levels_missing >> (i - 1) & 1:
                    self._allocate(level + i, shift_keys(absent, i))
            flags[missing] = self._launch_fill(
                level, depth, below, stores, absent, None if cells is None else cells[missing]
            )
            if np.any(flags < 0):
                raise RuntimeError(
                    f"coarse levels {level + 1}-{level + depth}: a parent block is missing (a vogjax bug)"
                )
        if self.releases:
            emptied = keys[(flags & levels.REGION_OBSERVED) == 0]
            for i, store in enumerate(stores, start=1):
                if len(emptied):
                    self._release_empty(store, np.unique(shift_keys(emptied, i)))
        if level + depth == self.count:  # nothing above to pass up to
            return np.zeros(0, np.int64)
        changed = (flags & (levels.LEVEL_CHANGED << (depth - 1))) != 0
        return np.unique(shift_keys(keys[changed], depth)) if changed.any() else np.zeros(0, np.int64)

    def _allocate(self, level: int, keys: np.ndarray) -> None:
        """Blocks for the packed keys `keys` (repeats allowed) in `level`, where missing."""
        self.store(level).ensure_blocks(np.unique(keys))

    def _launch_fill(
        self, level: int, depth: int, below: BlockStore, stores: list, keys: np.ndarray, cells: np.ndarray | None
    ) -> np.ndarray:
        """fill_levels_above_blocks over `keys`: the flags (len(keys),) int32, on the host."""
        padded = stores + [stores[-1]] * (3 - depth)  # levels past `depth` are neither read nor written
        arrays = [below.table_keys, below.table_slots, below.layers["log_odds"]]
        arrays += [a for store in padded for a in (store.table_keys, store.table_slots)]
        arrays += [store.layers["log_odds"] for store in padded]
        device = self.device
        # a block is 512 reads: one scan's few dozen stay on one thread
        parts = parallel.num_parts(device, len(keys) * 8)
        if parts == 1 and not device.is_cuda:
            return self._recorded_fill(level, depth, arrays, keys, cells).copy()
        d_keys = wp.array(keys, dtype=wp.int64, device=device)
        d_cells = wp.array(np.full(len(keys), ALL_CELLS) if cells is None else cells, dtype=wp.uint64, device=device)
        flags = wp.empty(len(keys), dtype=wp.int32, device=device)
        edges = [len(keys) * part // parts for part in range(parts + 1)]
        counts = wp.array(np.diff(edges).astype(np.int32), dtype=wp.int32, device=device)

        def fill(part: int, lo: int, hi: int) -> None:
            wp.launch(
                levels.fill_levels_above_blocks,
                dim=hi - lo,
                inputs=[d_keys[lo:hi], d_cells[lo:hi], counts[part : part + 1], depth, *arrays],
                outputs=[flags[lo:hi]],
                device=device,
            )

        parallel.split_launch(fill, len(keys), parts)
        return flags.numpy()

    def _recorded_fill(
        self, level: int, depth: int, arrays: list, keys: np.ndarray, cells: np.ndarray | None
    ) -> np.ndarray:
        """fill_levels_above_blocks on a CPU, one thread, its launch replayed (`replay.Replay`):
        an update after every scan is one launch of a few dozen blocks, where packing sixteen
        arguments costs as much as the kernel. Returns the flags (len(keys),), a view of its
        buffer (the next launch overwrites it)."""
        cached = self._launches.get(level)
        if cached is None or len(cached[1]) < len(keys):
            capacity = max(len(keys), 2 * len(cached[1]) if cached else 0, 256)
            d_keys = wp.empty(capacity, dtype=wp.int64, device=self.device)
            d_cells = wp.empty(capacity, dtype=wp.uint64, device=self.device)
            count = wp.zeros(1, dtype=wp.int32, device=self.device)
            flags = wp.empty(capacity, dtype=wp.int32, device=self.device)
            replay = Replay(levels.fill_levels_above_blocks, self.device)
            host = (d_keys.numpy(), d_cells.numpy(), count.numpy(), flags.numpy())
            cached = (replay, *host, (d_keys, d_cells, count, flags))
            self._launches[level] = cached
        replay, host_keys, host_cells, host_count, host_flags, (d_keys, d_cells, count, flags) = cached
        host_keys[: len(keys)] = keys
        host_cells[: len(keys)] = ALL_CELLS if cells is None else cells
        host_count[0] = len(keys)
        # threads past count[0] return at once: a dimension rounded up to a power of two is
        # rarely set anew, where setting it costs as much as a few dozen idle threads
        dim = min(1 << (len(keys) - 1).bit_length(), len(host_keys))
        replay(dim, [d_keys, d_cells, count, depth, *arrays], [flags])
        return host_flags[: len(keys)]

    def _release_empty(self, store: BlockStore, keys: np.ndarray) -> None:
        """Release those of the coarse blocks `keys` (distinct, live) that hold no observed voxel."""
        d_keys = wp.array(keys, dtype=wp.int64, device=self.device)
        holds = wp.empty(len(keys), dtype=wp.int32, device=self.device)
        wp.launch(
            levels.find_observed_blocks,
            dim=len(keys),
            inputs=[d_keys, store.table_keys, store.table_slots, store.layers["log_odds"]],
            outputs=[holds],
            device=self.device,
        )
        empty = holds.numpy() == 0
        if empty.any():
            store.release(store.find(d_keys).numpy()[empty])


def _merge_noted(noted: list) -> tuple[np.ndarray, np.ndarray | None]:
    """The distinct keys (sorted, EMPTY_KEY dropped) of noted (keys, cells) pairs, each with
    the union of its cells (None when no pair had cells: all of them)."""
    keys = np.concatenate([k for k, _ in noted]) if len(noted) > 1 else noted[0][0]
    if all(c is None for _, c in noted):
        distinct, cells = np.unique(keys), None
    else:
        every = np.concatenate([np.full(len(k), ALL_CELLS) if c is None else c for k, c in noted])
        distinct, inverse = np.unique(keys, return_inverse=True)
        cells = np.zeros(len(distinct), np.uint64)
        np.bitwise_or.at(cells, inverse, every)
    if len(distinct) and distinct[0] == EMPTY_KEY:  # sorted: EMPTY_KEY (-1) first, at most once
        distinct = distinct[1:]
        cells = None if cells is None else cells[1:]
    return distinct, cells


def _live_keys(store: BlockStore) -> np.ndarray:
    keys = store.slot_keys.numpy()[: store.num_blocks]
    return keys[keys != EMPTY_KEY]
