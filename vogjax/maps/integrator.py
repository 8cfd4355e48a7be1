"""Batched scan integration into a BlockStore: passes of scans through kernels/integration.py.

Each pass marks every beam once into a scratch (a table of the blocks the pass touches and two
bits per scan for each of their voxels), allocates the touched blocks in the map, and replays the
marks voxel by voxel. The scratch is shared by the maps of a device (taken from a pool for the
length of one call), so a thousand submaps do not each hold one.
"""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import warp as wp

from vogjax.config import MapConfig
from vogjax.kernels import integration
from vogjax.kernels.hashing import BLOCK_EDGE, BLOCK_VOXELS, EMPTY_KEY
from vogjax.maps import parallel
from vogjax.maps.blocks import BlockStore

# A pass's bounding box (in blocks) with at most this many cells is indexed densely: a block's
# scratch table look-up is then one load with no hashing.
DENSE_CELLS = 1 << 18
_MIN_BLOCKS = 64


@dataclasses.dataclass(frozen=True)
class Beams:
    """One batch of beams on the device: origins (S,3) float32, points (N,3) float32, and
    ray_scan (N,) int32 the scan of each point, sorted; the host keeps `scan_index` (N,)."""

    origins: wp.array
    points: wp.array
    ray_scan: wp.array
    scan_index: np.ndarray
    host_points: np.ndarray  # (N,3) and (S,3): the host copies, for the passes' boxes
    host_origins: np.ndarray


class Scratch:
    """Per part p (a CPU thread; one on CUDA): a table of the pass's blocks, their keys and
    table positions by number, counters (blocks numbered, probe failures) and the marks."""

    def __init__(self, device, parts: int):
        self.device = device
        self.parts = parts
        self.touched: list | None = None  # where a call collects the keys of the blocks it wrote
        self._tables(1024)
        self._blocks(_MIN_BLOCKS * BLOCK_VOXELS * 2)

    def _tables(self, capacity: int) -> None:
        self.table_keys = wp.full((self.parts, capacity), EMPTY_KEY, dtype=wp.int64, device=self.device)
        self.table_index = wp.full((self.parts, capacity), -1, dtype=wp.int32, device=self.device)
        self._rows = None

    def _blocks(self, mark_words: int) -> None:
        blocks = mark_words // BLOCK_VOXELS
        self.block_keys = wp.full((self.parts, blocks), EMPTY_KEY, dtype=wp.int64, device=self.device)
        self.table_position = wp.zeros((self.parts, blocks), dtype=wp.int32, device=self.device)
        self.counters = wp.zeros((self.parts, 2), dtype=wp.int32, device=self.device)
        self.marks = wp.zeros((self.parts, mark_words), dtype=wp.uint64, device=self.device)
        # (blocks, 1): block u is number u of part 0, the replay's block list for one part
        self.numbers = wp.array(np.arange(blocks, dtype=np.int32)[:, None], dtype=wp.int32, device=self.device)
        # per block of a pass (the parts' distinct blocks: up to parts * blocks), the 2x2x2 cells
        # whose voxels changed (for the coarse levels)
        self.cell_masks = wp.zeros(self.parts * blocks, dtype=wp.uint64, device=self.device)
        # on a CPU, the same memory as NumPy: slicing a Warp array costs more than the launch
        self.cell_masks_host = None if self.device.is_cuda else self.cell_masks.numpy()
        self._rows = None

    def part_rows(self, part: int) -> tuple:
        """Part `part`'s rows of the arrays mark_beams writes (views made once per allocation:
        indexing a 2-D Warp array costs more Python time than the launch's other arguments)."""
        if self._rows is None:
            arrays = (
                self.table_keys,
                self.table_index,
                self.table_position,
                self.block_keys,
                self.counters,
                self.marks,
            )
            self._rows = [tuple(a[p] for a in arrays) for p in range(self.parts)]
        return self._rows[part]

    @property
    def table_capacity(self) -> int:
        return self.table_keys.shape[1]

    def block_capacity(self, words: int) -> int:
        return min(self.block_keys.shape[1], self.marks.shape[1] // (BLOCK_VOXELS * words))

    def fit(self, blocks: int, words: int, cells: int) -> None:
        """Room for `blocks` blocks of `words` words per voxel, and a table for `cells` dense cells."""
        if self.block_capacity(words) < blocks:
            self._blocks(max(blocks, 2 * self.block_capacity(words)) * BLOCK_VOXELS * words)
        wanted = _power_of_two(max(cells, 2 * self.block_keys.shape[1], 1024))
        if wanted > self.table_capacity:
            self._tables(wanted)

    def bytes_for(self, blocks: int, words: int) -> int:
        return self.parts * blocks * BLOCK_VOXELS * words * 8

    def clear(self) -> None:
        """Back to empty after a pass that was abandoned (overflow or budget)."""
        self.table_keys.fill_(EMPTY_KEY)
        self.table_index.fill_(-1)
        self.marks.zero_()
        self.counters.zero_()

    def memory_bytes(self) -> int:
        arrays = (self.table_keys, self.table_index, self.block_keys, self.table_position, self.counters, self.marks)
        return int(sum(a.capacity for a in arrays))


_pool: dict = {}
_pool_lock = threading.Lock()


def _take(device, parts: int) -> Scratch:
    with _pool_lock:
        free = _pool.setdefault((str(device), parts), [])
        if free:
            return free.pop()
    return Scratch(device, parts)


def _give(scratch: Scratch) -> None:
    with _pool_lock:
        _pool[(str(scratch.device), scratch.parts)].append(scratch)


def beams(device, origins: np.ndarray, points: np.ndarray, scan_index: np.ndarray) -> Beams:
    """A validated batch (scan_index sorted) on the device: copies on a GPU; on a CPU, Warp
    arrays over the contiguous float32 / int32 host arrays (the kernels only read them)."""
    copy = device.is_cuda
    return Beams(
        wp.array(origins, dtype=wp.vec3f, device=device, copy=copy),
        wp.array(points, dtype=wp.vec3f, device=device, copy=copy),
        wp.array(scan_index, dtype=wp.int32, device=device, copy=copy),
        scan_index,
        points,
        origins,
    )


def integrate(
    store: BlockStore,
    config: MapConfig,
    batch: Beams,
    scans_per_pass: int,
    budget_bytes: int,
    touched: list | None = None,
) -> None:
    """Integrate every scan of `batch`, `scans_per_pass` at a time, into `store`; with a
    `touched` list, append to it per pass the packed keys (K,) int64 of the blocks written and
    their changed cells (K,) uint64 (`Levels.note`)."""
    num_scans = batch.host_origins.shape[0]
    if batch.scan_index.shape[0] == 0:
        return
    firsts = np.arange(0, num_scans, scans_per_pass)
    bounds = np.searchsorted(batch.scan_index, np.append(firsts, num_scans))
    boxes = _boxes(batch, firsts, bounds, config.voxel_size)
    parts = parallel.num_parts(store.device, int(np.diff(bounds).max()))
    scratch = _take(store.device, parts)
    scratch.touched = touched
    try:
        blocks_per_scan = 0.0
        for k, first in enumerate(firsts.tolist()):
            if bounds[k + 1] > bounds[k]:
                last = min(first + scans_per_pass, num_scans)
                blocks_per_scan = _pass(
                    store,
                    config,
                    batch,
                    scratch,
                    first,
                    last,
                    int(bounds[k]),
                    int(bounds[k + 1]),
                    budget_bytes,
                    boxes[k],
                    blocks_per_scan,
                )
    finally:
        scratch.touched = None
        _give(scratch)


def _pass(
    store: BlockStore,
    config: MapConfig,
    batch: Beams,
    scratch: Scratch,
    first: int,
    last: int,
    lo: int,
    hi: int,
    budget_bytes: int,
    box: tuple,
    blocks_per_scan: float = 0.0,
) -> float:
    """Scans [first, last), whose beams are rows [lo, hi) of the batch, inside `box`:
    (lowest block (3,), blocks per axis (3,)), a box holding every block the pass can touch.

    Returns the blocks per scan a part numbered, the estimate for the next pass: a pass that the
    estimate puts over the budget is split before it is marked, not after (marking it first
    would double the work of every pass in a wide scene)."""
    if hi == lo:
        return blocks_per_scan
    words = (last - first + integration.SCANS_PER_WORD - 1) // integration.SCANS_PER_WORD
    if last - first > 1 and scratch.bytes_for(int(blocks_per_scan * (last - first)), words) > budget_bytes:
        return _halves(store, config, batch, scratch, first, last, lo, hi, budget_bytes, box, blocks_per_scan)
    box_lo, box_dims = box
    cells = int(np.prod(box_dims))
    dense = cells <= DENSE_CELLS
    blocks = 0
    while True:
        scratch.fit(blocks, words, cells if dense else 0)
        capacity = scratch.block_capacity(words)
        _mark(config, batch, scratch, first, lo, hi, capacity, (box_lo, box_dims) if dense else None)
        counters = scratch.counters.numpy()
        numbered, missed = int(counters[:, 0].max()), bool(counters[:, 1].any())
        over_budget = scratch.bytes_for(numbered, words) > budget_bytes and last - first > 1
        if numbered <= capacity and not missed and not over_budget:
            break
        scratch.clear()
        if over_budget:
            return _halves(
                store, config, batch, scratch, first, last, lo, hi, budget_bytes, box, numbered / (last - first)
            )
        if missed and dense:
            dense = False  # a walk left the box (round-off past its margin): look blocks up by hash
        blocks = numbered + numbered // 4 + (capacity if missed else 0)
    _apply(store, config, scratch, counters[:, 0], words, capacity)
    return numbered / (last - first)


def _halves(
    store: BlockStore,
    config: MapConfig,
    batch: Beams,
    scratch: Scratch,
    first: int,
    last: int,
    lo: int,
    hi: int,
    budget_bytes: int,
    box: tuple,
    blocks_per_scan: float,
) -> float:
    """The pass as two half passes: the same map, as the scans replay in order either way."""
    middle = (first + last) // 2
    split = lo + int(np.searchsorted(batch.scan_index[lo:hi], middle))
    blocks_per_scan = _pass(store, config, batch, scratch, first, middle, lo, split, budget_bytes, box, blocks_per_scan)
    return _pass(store, config, batch, scratch, middle, last, split, hi, budget_bytes, box, blocks_per_scan)


def _boxes(batch: Beams, firsts: np.ndarray, bounds: np.ndarray, voxel_size: float) -> list:
    """Per pass (scans from firsts[k], beams bounds[k]:bounds[k+1]), a box of blocks holding its
    origins and points, so every beam (cut beams end between them); a block of margin covers
    walks that round-off carries a voxel or two further. Passes without beams get None."""
    some = bounds[:-1] < bounds[1:]
    starts = bounds[:-1][some]  # increasing: each segment runs to the next pass with beams
    points, origins = batch.host_points, batch.host_origins
    if len(starts) <= _FEW_PASSES:  # few long segments (GPU passes): see _extremes
        ends = np.append(starts[1:], points.shape[0]).tolist()
        extremes = [_extremes(points, a, b) for a, b in zip(starts.tolist(), ends)]
        p_low, p_high = np.array([e[0] for e in extremes]), np.array([e[1] for e in extremes])
    else:
        p_low, p_high = np.minimum.reduceat(points, starts, axis=0), np.maximum.reduceat(points, starts, axis=0)
    low = np.minimum(p_low, np.minimum.reduceat(origins, firsts, axis=0)[some]).astype(np.float64)
    high = np.maximum(p_high, np.maximum.reduceat(origins, firsts, axis=0)[some]).astype(np.float64)
    # float32 -> float64 is monotonic: the extreme keys are those of the extreme coordinates
    inv = 1.0 / voxel_size
    block_lo = np.floor(low * inv).astype(np.int64) // BLOCK_EDGE - 1
    block_hi = np.floor(high * inv).astype(np.int64) // BLOCK_EDGE + 1
    boxes = iter(zip(block_lo.tolist(), (block_hi - block_lo + 1).tolist()))
    return [tuple(next(boxes)) if ok else None for ok in some]


_FEW_PASSES = 8


def _extremes(array: np.ndarray, lo: int, hi: int) -> tuple:
    """Per-column minimum and maximum (3,) of rows [lo, hi) (hi > lo) of an (N,3) array. A
    reduction over axis 0 of rows of three runs one row at a time; rows taken 256 at a time, as
    rows of 768, reduce some ten times faster (min and max are exact: the same values)."""
    rows = 256
    whole = lo + (hi - lo) // rows * rows
    parts = [array[whole:hi]] if hi > whole else []
    if whole > lo:
        wide = array[lo:whole].reshape(-1, 3 * rows)
        parts += [wide.min(axis=0).reshape(rows, 3), wide.max(axis=0).reshape(rows, 3)]
    stacked = np.concatenate(parts) if len(parts) > 1 else parts[0]
    return stacked.min(axis=0), stacked.max(axis=0)


def _mark(config: MapConfig, batch: Beams, scratch: Scratch, first: int, lo: int, hi: int, capacity: int, box) -> None:
    device = scratch.device
    scalars = [first, np.float64(config.max_range), np.float64(config.voxel_size), np.float64(1.0 / config.voxel_size)]
    box_lo, box_dims = box if box is not None else ((0, 0, 0), (0, 0, 0))
    scalars += [wp.vec3i(*box_lo), wp.vec3i(*box_dims)]

    def launch(part: int, a: int, b: int) -> None:
        wp.launch(
            integration.mark_beams,
            dim=b - a,
            inputs=[batch.origins, batch.points[lo + a : lo + b], batch.ray_scan[lo + a : lo + b], *scalars, capacity],
            outputs=scratch.part_rows(part),
            device=device,
        )

    parallel.split_launch(launch, hi - lo, scratch.parts)


def _apply(
    store: BlockStore, config: MapConfig, scratch: Scratch, numbered: np.ndarray, words: int, capacity: int
) -> None:
    device, parts = scratch.device, scratch.parts
    if parts == 1:
        keys = scratch.part_rows(0)[3][: int(numbered[0])]
        d_part_blocks = scratch.numbers[: int(numbered[0])]  # on the device already
    else:
        # the parts numbered their blocks independently: list each distinct block's numbers
        host = scratch.block_keys.numpy()
        every = np.concatenate([host[p, : numbered[p]] for p in range(parts)])
        unique, inverse = np.unique(every, return_inverse=True)
        part_blocks = np.full((unique.shape[0], parts), -1, dtype=np.int32)
        offsets = np.concatenate([[0], np.cumsum(numbered)])
        for p in range(parts):
            part_blocks[inverse[offsets[p] : offsets[p + 1]], p] = np.arange(numbered[p], dtype=np.int32)
        keys = wp.array(unique, dtype=wp.int64, device=device)
        d_part_blocks = wp.array(part_blocks, dtype=wp.int32, device=device)
    count = d_part_blocks.shape[0]
    if count == 0:
        scratch.counters.zero_()
        return
    store.ensure_blocks(keys)
    slots = store.find(keys)
    record = scratch.touched is not None
    if record and scratch.cell_masks_host is not None:
        scratch.cell_masks_host[:count] = 0
    elif record:
        scratch.cell_masks[:count].zero_()
    inputs = [
        words,
        capacity,
        config.log_hit,
        config.log_miss,
        config.log_clamp_min,
        config.log_clamp_max,
        scratch.marks,
        scratch.table_keys,
        scratch.table_index,
        scratch.table_position,
    ]
    voxels = count * BLOCK_VOXELS
    # on a GPU, passes have many words per voxel, and a thread's registers are few
    kernel = (
        integration.apply_marks_few_words
        if words <= integration.FEW_WORDS and not device.is_cuda
        else integration.apply_marks
    )
    # split at block boundaries: a block's cell mask is ORed by its voxels' threads, and CPU
    # atomics are plain read-modify-writes
    parallel.split_launch(
        lambda part, a, b: wp.launch(
            kernel,
            dim=(b - a) * BLOCK_VOXELS,
            inputs=[slots, d_part_blocks, a * BLOCK_VOXELS, *inputs, int(record)],
            outputs=[store.layers["log_odds"], scratch.cell_masks],
            device=device,
        ),
        count,
        min(count, parallel.num_parts(device, voxels)),
    )
    if record:  # copies: on a CPU, numpy() views the scratch the next pass reuses
        masks = scratch.cell_masks_host if scratch.cell_masks_host is not None else scratch.cell_masks.numpy()
        scratch.touched.append((np.array(keys.numpy()), masks[:count].copy()))
    scratch.counters.zero_()


def _power_of_two(n: int) -> int:
    return 1 << max(0, math.ceil(math.log2(max(n, 1))))
