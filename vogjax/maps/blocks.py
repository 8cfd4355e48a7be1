"""Hashed storage of dense 8x8x8 voxel blocks in Warp arrays.

The table maps packed block coordinates to slots; each voxel layer is one flat array of
`block_capacity * 512` values, block `slot` at `[slot*512, (slot+1)*512)`. Table and pool grow
(the table by rehashing) before anything would overflow: nothing is ever dropped.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import warp as wp

from vogjax.kernels import hashing
from vogjax.maps.replay import Replay

BLOCK_EDGE = hashing.BLOCK_EDGE
BLOCK_VOXELS = hashing.BLOCK_VOXELS
EMPTY_KEY = -1
_FIELD = (1 << 21) - 1
_BIAS = 1 << 20
_MIN_TABLE = 1024
_MIN_BLOCKS = 64
# A block grid (BlockGrid) is built when the blocks' box has at most this many cells (16 MiB).
GRID_CELLS = 1 << 22


def pack_blocks(blocks: np.ndarray) -> np.ndarray:
    """(K,3) int block coordinates -> (K,) packed int64 keys (host side of `hashing.pack_block`)."""
    b = blocks.astype(np.int64) + _BIAS
    return (b[:, 0] << 42) | (b[:, 1] << 21) | b[:, 2]


def unpack_blocks(keys: np.ndarray) -> np.ndarray:
    """(K,) packed keys -> (K,3) int64 block coordinates."""
    keys = keys.astype(np.int64)
    return np.stack([(keys >> 42) & _FIELD, (keys >> 21) & _FIELD, keys & _FIELD], axis=1) - _BIAS


def check_block_keys(keys: np.ndarray, where: str) -> None:
    """ValueError naming `where` unless `keys` (K,) int64 are distinct packed block coordinates
    within the key range (not the table's empty or tombstone marks, nothing in the spare bits)."""
    if keys.dtype != np.int64 or keys.ndim != 1:
        raise ValueError(f"{where} has block keys of type {keys.dtype} and shape {keys.shape}, not (K,) int64")
    blocks = unpack_blocks(keys)
    limit = hashing.VOXEL_KEY_LIMIT // BLOCK_EDGE
    if len(keys) and (keys.min() < 0 or np.any(pack_blocks(blocks) != keys) or np.abs(blocks).max() >= limit):
        raise ValueError(f"{where} holds block keys that are no packed block coordinates")
    if len(np.unique(keys)) != len(keys):
        raise ValueError(f"{where} holds a block twice")


def voxel_keys(block_keys: np.ndarray, block_index: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(K,3) voxel keys of voxel `local` (0..511) in block `block_keys[block_index]`."""
    return unpack_blocks(block_keys)[block_index] * BLOCK_EDGE + voxel_offsets()[local]


def voxel_offsets() -> np.ndarray:
    """(512,3) voxel offsets inside a block, in the order of `hashing.index_in_block`."""
    i = np.arange(BLOCK_VOXELS)
    return np.stack([i // 64, (i // 8) % 8, i % 8], axis=1)


@dataclasses.dataclass(frozen=True)
class BlockGrid:
    """The box of a store's blocks and, when small enough, a dense index of it for queries.

    lo, hi: (3,) int lowest and highest block coordinates of the blocks (hi < lo: no blocks)
    dims: (3,) int cells per axis of `cells`, all 0 when there is no dense index
    cells: int32 (prod(dims),) slot of the block in each cell, -1 where none (one -1 without index)
    """

    lo: tuple
    hi: tuple
    dims: tuple
    cells: wp.array

    @property
    def voxel_lo(self) -> tuple:
        return tuple(int(v) * BLOCK_EDGE for v in self.lo)

    @property
    def voxel_hi(self) -> tuple:
        return tuple(int(v) * BLOCK_EDGE + BLOCK_EDGE - 1 for v in self.hi)


class BlockStore:
    """Blocks of voxel layers addressed by an open-addressing hash table on one device.

    layers: name -> (Warp scalar dtype, value of a voxel nobody wrote yet)
    """

    def __init__(self, device, layers: dict, block_capacity: int = _MIN_BLOCKS):
        self.device = device
        self.layer_specs = dict(layers)
        self.num_blocks = 0  # slots handed out so far, released ones included
        self.free_slots: list[int] = []  # released slots, reused before new ones
        self.tombstones = 0  # table entries of released blocks, cleared by the next rehash
        self.table_keys = wp.full(_MIN_TABLE, EMPTY_KEY, dtype=wp.int64, device=device)
        self.table_slots = wp.full(_MIN_TABLE, -1, dtype=wp.int32, device=device)
        capacity = max(block_capacity, _MIN_BLOCKS)
        self.slot_keys = wp.full(capacity, EMPTY_KEY, dtype=wp.int64, device=device)
        self.layers = {
            name: wp.full(capacity * BLOCK_VOXELS, fill, dtype=dtype, device=device)
            for name, (dtype, fill) in self.layer_specs.items()
        }
        self.version = 0  # counts changes to the set of blocks (BlockGrid follows it)
        self._new_positions = wp.empty(0, dtype=wp.int32, device=device)  # ensure_blocks' scratch
        self._counters = wp.zeros(2, dtype=wp.int32, device=device)
        # on a CPU the counters are read in place, and the keys to insert are copied into one
        # array the recorded launches keep (a scan allocates a few dozen blocks: the launches'
        # set-up, not the kernels, was most of the cost)
        self._counters_view = None if device.is_cuda else self._counters.numpy()
        self._staged = wp.empty(0, dtype=wp.int64, device=device)
        self._staged_view = self._staged.numpy() if not device.is_cuda else None
        self._insert = Replay(hashing.insert_keys, device)
        self._assign = Replay(hashing.assign_slots, device)
        self._no_slots = wp.empty(0, dtype=wp.int32, device=device)  # no released slots to reuse
        self._grid: tuple | None = None  # (version, BlockGrid)
        self._box: tuple | None = None  # (version, block_box())
        self._grid_lock = threading.Lock()

    @property
    def block_capacity(self) -> int:
        return self.slot_keys.shape[0]

    @property
    def table_capacity(self) -> int:
        return self.table_keys.shape[0]

    @property
    def live_blocks(self) -> int:
        return self.num_blocks - len(self.free_slots)

    def memory_bytes(self) -> int:
        arrays = [self.table_keys, self.table_slots, self.slot_keys, *self.layers.values()]
        grid = self._grid
        return int(sum(a.capacity for a in arrays)) + (grid[1].cells.capacity if grid else 0)

    def grid(self) -> BlockGrid:
        """The blocks' box and dense index, rebuilt after blocks were added or released (call
        it under the owner's read lock; concurrent readers share one build)."""
        with self._grid_lock:
            if self._grid is None or self._grid[0] != self.version:
                self._grid = (self.version, self._build_grid())
            return self._grid[1]

    def block_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lo, hi): the lowest and highest block coordinates (3,) int64 of the blocks, None when
        there are none (read back once per change to the set of blocks)."""
        with self._grid_lock:
            return self._current_box()

    def _current_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        # under _grid_lock
        if self._box is None or self._box[0] != self.version:
            keys = self.slot_keys.numpy()[: self.num_blocks]
            blocks = unpack_blocks(keys[keys != EMPTY_KEY])
            self._box = (self.version, (blocks.min(axis=0), blocks.max(axis=0)) if len(blocks) else None)
        return self._box[1]

    def _build_grid(self) -> BlockGrid:
        none = wp.full(1, -1, dtype=wp.int32, device=self.device)
        box = self._current_box()
        if box is None:
            return BlockGrid((1, 1, 1), (0, 0, 0), (0, 0, 0), none)
        lo, hi = box
        dims = hi - lo + 1
        box = (tuple(lo.tolist()), tuple(hi.tolist()))
        if int(np.prod(dims)) > GRID_CELLS:
            return BlockGrid(*box, (0, 0, 0), none)
        cells = wp.full(int(np.prod(dims)), -1, dtype=wp.int32, device=self.device)
        wp.launch(
            hashing.fill_block_grid,
            dim=self.num_blocks,
            inputs=[self.slot_keys, wp.vec3i(*box[0]), wp.vec3i(*dims.tolist())],
            outputs=[cells],
            device=self.device,
        )
        return BlockGrid(*box, tuple(dims.tolist()), cells)

    def ensure_blocks(self, keys: wp.array | np.ndarray) -> None:
        """Allocate a block for every packed key in `keys` (K,) int64, a Warp array on the store's
        device or a NumPy array (EMPTY_KEY entries are skipped)."""
        count = keys.shape[0]
        if count == 0:
            return
        keys = self._stage(keys)
        if self._new_positions.shape[0] < count:
            self._new_positions = wp.empty(count + count // 2, dtype=wp.int32, device=self.device)
        # room for every key first (keys may repeat: at most their number are new): inserting
        # into a table they would overfill fails part-way, and costs a second round
        if 2 * (self.live_blocks + self.tombstones + count) > self.table_capacity:
            self._reserve_table(self.live_blocks + count)
        while True:
            new_blocks, failed = self._insert_keys(keys, count)
            if new_blocks:
                reused = self.free_slots[:new_blocks]
                del self.free_slots[:new_blocks]
                fresh = new_blocks - len(reused)
                self._reserve_blocks(self.num_blocks + fresh)
                reused_slots = (
                    wp.array(np.asarray(reused, np.int32), dtype=wp.int32, device=self.device)
                    if reused
                    else self._no_slots
                )
                self._assign(
                    new_blocks,
                    [self._new_positions, reused_slots, self.num_blocks],
                    [self.table_keys, self.table_slots, self.slot_keys],
                )
                self.num_blocks += fresh
                self.version += 1
            if failed:  # insertions stopped at a full table: four times the room, then again
                self._reserve_table(max(self.live_blocks + self.live_blocks // 2, 2 * self.table_capacity))
            elif 2 * (self.live_blocks + self.tombstones) > self.table_capacity:
                self._reserve_table(self.live_blocks + self.live_blocks // 2)
            if not failed:
                return

    def _stage(self, keys: wp.array | np.ndarray) -> wp.array:
        """The keys as a Warp array on the device: on a CPU, copied into the one array the
        recorded insertion reads (only its first len(keys) entries are read)."""
        if self.device.is_cuda:
            return keys if isinstance(keys, wp.array) else wp.array(np.asarray(keys, np.int64), device=self.device)
        count = keys.shape[0]
        if self._staged.shape[0] < count:
            self._staged = wp.empty(max(count, 2 * self._staged.shape[0], 256), dtype=wp.int64, device=self.device)
            self._staged_view = self._staged.numpy()
        self._staged_view[:count] = keys.numpy() if isinstance(keys, wp.array) else keys
        return self._staged

    def _insert_keys(self, keys: wp.array, count: int) -> tuple[int, int]:
        """insert_keys over keys[:count]: (keys new to the table, insertions that failed)."""
        if self._counters_view is None:
            self._counters.zero_()
        else:
            self._counters_view[:] = 0
        self._insert(count, [keys], [self.table_keys, self._new_positions, self._counters])
        counters = self._counters.numpy() if self._counters_view is None else self._counters_view
        return int(counters[0]), int(counters[1])

    def release(self, slots: np.ndarray) -> None:
        """Drop the blocks in `slots` (distinct, live): their slots are reused, their layers reset."""
        if len(slots) == 0:
            return
        wp.launch(
            hashing.remove_slots,
            dim=len(slots),
            inputs=[wp.array(np.asarray(slots, np.int32), dtype=wp.int32, device=self.device)],
            outputs=[self.table_keys, self.table_slots, self.slot_keys],
            device=self.device,
        )
        for slot in slots:
            for name, (_, fill) in self.layer_specs.items():
                self.layers[name][int(slot) * BLOCK_VOXELS : (int(slot) + 1) * BLOCK_VOXELS].fill_(fill)
        self.free_slots.extend(int(s) for s in slots)
        self.tombstones += len(slots)
        self.version += 1
        if 2 * (self.live_blocks + self.tombstones) > self.table_capacity:
            self._reserve_table(self.live_blocks)

    def find(self, keys: wp.array) -> wp.array:
        """Slots of packed keys, -1 where absent."""
        slots = wp.empty(keys.shape[0], dtype=wp.int32, device=self.device)
        if keys.shape[0]:
            wp.launch(
                hashing.resolve_slots,
                dim=keys.shape[0],
                inputs=[keys, self.table_keys, self.table_slots],
                outputs=[slots],
                device=self.device,
            )
        return slots

    def host_blocks(self) -> tuple[np.ndarray, dict]:
        """Packed keys (K,) sorted ascending and each layer as (K,512), copied to the host."""
        keys = self.slot_keys.numpy()[: self.num_blocks]
        order = np.argsort(keys, kind="stable")
        order = order[keys[order] != EMPTY_KEY]  # released slots
        layers = {
            name: array.numpy()[: self.num_blocks * BLOCK_VOXELS].reshape(self.num_blocks, BLOCK_VOXELS)[order]
            for name, array in self.layers.items()
        }
        return keys[order], layers

    def copy(self) -> BlockStore:
        """An independent store holding the same blocks in the same slots (the arrays cloned)."""
        other = BlockStore(self.device, self.layer_specs)
        other.num_blocks, other.free_slots, other.tombstones = self.num_blocks, list(self.free_slots), self.tombstones
        other.table_keys, other.table_slots = wp.clone(self.table_keys), wp.clone(self.table_slots)
        other.slot_keys = wp.clone(self.slot_keys)
        other.layers = {name: wp.clone(array) for name, array in self.layers.items()}
        other.version = self.version
        return other

    @classmethod
    def from_host(cls, device, layers: dict, keys: np.ndarray, values: dict) -> BlockStore:
        """A store holding host blocks: packed keys (K,) and each layer as (K,512)."""
        count = int(keys.shape[0])
        store = cls(device, layers, block_capacity=count)
        if count == 0:
            return store
        store.slot_keys[:count].assign(wp.array(keys.astype(np.int64), dtype=wp.int64, device=device))
        for name, array in values.items():
            flat = np.ascontiguousarray(array).reshape(-1)
            store.layers[name][: flat.shape[0]].assign(wp.array(flat, dtype=store.layer_specs[name][0], device=device))
        store.num_blocks = count
        capacity = _MIN_TABLE
        while capacity < 2 * count:
            capacity *= 2
        store._rehash(capacity)
        return store

    def _reserve_table(self, num_keys: int) -> None:
        """Grow the table so `num_keys` keys fill at most half of it; rehashing clears tombstones."""
        capacity = self.table_capacity
        while capacity < 2 * num_keys:
            capacity *= 2
        if capacity != self.table_capacity or self.tombstones:
            self._rehash(capacity)

    def _rehash(self, capacity: int) -> None:
        self.tombstones = 0
        self._insert.forget()  # they hold the old table
        self._assign.forget()
        self.table_keys = wp.full(capacity, EMPTY_KEY, dtype=wp.int64, device=self.device)
        self.table_slots = wp.full(capacity, -1, dtype=wp.int32, device=self.device)
        if self.num_blocks:
            wp.launch(
                hashing.reinsert_slots,
                dim=self.num_blocks,
                inputs=[self.slot_keys],
                outputs=[self.table_keys, self.table_slots],
                device=self.device,
            )

    def _reserve_blocks(self, num_blocks: int) -> None:
        old = self.block_capacity
        if num_blocks <= old:
            return
        # Steps of a quarter: a map grown pass by pass copies its pool about four times in all
        # (a few milliseconds for a 2000-scan survey) and holds at most a fifth of it spare.
        capacity = max(num_blocks, old + old // 4)
        self._assign.forget()  # it holds the old slot keys
        self.slot_keys = _grown(self.slot_keys, capacity, EMPTY_KEY)
        for name, (_, fill) in self.layer_specs.items():
            self.layers[name] = _grown(self.layers[name], capacity * BLOCK_VOXELS, fill)


def _grown(array: wp.array, size: int, fill) -> wp.array:
    grown = wp.empty(size, dtype=array.dtype, device=array.device)
    wp.copy(grown, array, count=array.shape[0])
    grown[array.shape[0] :].fill_(fill)
    return grown
