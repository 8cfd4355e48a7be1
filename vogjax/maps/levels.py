"""The coarse levels a block map keeps beside its level-0 blocks (`kernels/levels.py`).

Level k (1 <= k <= MAX_LEVEL) is a BlockStore of its own, of voxels 2^k times the map's edge,
each holding the maximum log-odds of its observed level-0 voxels (NaN: none observed), so the
queries of level 0 run on it unchanged with the voxel size scaled by 2^k. A map builds a level
the first time it is queried and from then on keeps every level it built current: after each
write it recomputes, level by level, the coarse blocks above the level-0 blocks it wrote, from
their children. A coarse block with no observed voxel left is released, so a level holds the
blocks a fresh build would, whatever happened before.

Measured in benchmarks/bench_octomap.py (docs/benchmarks/octomap.md).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.kernels import levels
from vogjax.maps import parallel
from vogjax.maps.blocks import EMPTY_KEY, BlockStore, pack_blocks, unpack_blocks

# OctoMap's depth 16 - k: level 15 is depth 1, the root's children. (The root, level 16, is not
# aligned with vogjax's keys: OctoMap's keys are offset by 2^15.)
MAX_LEVEL = 15
LAYERS = {"log_odds": (wp.float32, np.nan)}


def check_level(level) -> int:
    """`level` as an int in [0, MAX_LEVEL]; ValueError naming it otherwise."""
    if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, np.integer)) or not 0 <= level <= MAX_LEVEL:
        raise ValueError(
            f"level must be an integer in [0, {MAX_LEVEL}] (voxels of voxel_size * 2^level), got {level!r}"
        )
    return int(level)


def level_scales(voxel_size: float, level: int) -> tuple[np.float64, np.float64]:
    """(resolution, 1 / resolution) of level `level`, both exact powers of two times level 0's,
    so a point's coarse key is its level-0 key shifted right by `level`, bit for bit."""
    return np.float64(np.ldexp(voxel_size, level)), np.float64(np.ldexp(1.0 / voxel_size, -level))


def parent_keys(keys: np.ndarray) -> np.ndarray:
    """Distinct packed keys (K,) of the blocks one level up from packed block keys `keys`."""
    if len(keys) == 0:
        return np.zeros(0, np.int64)
    return np.unique(pack_blocks(unpack_blocks(keys) >> 1))


class Levels:
    """The coarse levels 1..count of one map, on its device."""

    def __init__(self, device):
        self.device = device
        self.stores: list[BlockStore] = []

    @property
    def count(self) -> int:
        """The coarsest level kept (0: none)."""
        return len(self.stores)

    def store(self, level: int) -> BlockStore:
        return self.stores[level - 1]

    def memory_bytes(self) -> int:
        return sum(store.memory_bytes() for store in self.stores)

    def extend(self, base: BlockStore, level: int) -> None:
        """Build levels count+1 .. `level` from scratch (each from the one below)."""
        while self.count < level:
            below = self.stores[-1] if self.stores else base
            store = BlockStore(self.device, LAYERS)
            self.stores.append(store)
            self._recompute(below, store, parent_keys(_live_keys(below)))

    def rebuild(self, base: BlockStore) -> None:
        """Every kept level from scratch (after the level-0 store was replaced)."""
        count = self.count
        self.stores = []
        self.extend(base, count)

    def update(self, base: BlockStore, keys: np.ndarray) -> None:
        """Bring every kept level up to date after the level-0 blocks with packed keys `keys`
        (any order, repeats allowed; released blocks included) were written."""
        below = base
        changed = np.unique(np.asarray(keys, np.int64))
        changed = changed[changed != EMPTY_KEY]
        for store in self.stores:
            if len(changed) == 0:
                return
            changed = parent_keys(changed)
            self._recompute(below, store, changed)
            below = store

    def _recompute(self, below: BlockStore, store: BlockStore, keys: np.ndarray) -> None:
        """Recompute the coarse blocks `keys` of `store` from `below`; release those left empty."""
        if len(keys) == 0:
            return
        device = self.device
        d_keys = wp.array(keys, dtype=wp.int64, device=device)
        store.ensure_blocks(d_keys)
        slots = store.find(d_keys)
        parallel.split_launch(
            lambda part, lo, hi: wp.launch(
                levels.fill_coarse_blocks,
                dim=(hi - lo) * 8,
                inputs=[
                    slots[lo:hi],
                    store.slot_keys,
                    below.table_keys,
                    below.table_slots,
                    below.layers["log_odds"],
                ],
                outputs=[store.layers["log_odds"]],
                device=device,
            ),
            len(keys),
            parallel.num_parts(device, len(keys) * 64),
        )
        flags = wp.empty(len(keys), dtype=wp.int32, device=device)
        wp.launch(
            levels.flag_unobserved_blocks,
            dim=len(keys),
            inputs=[slots, store.layers["log_odds"]],
            outputs=[flags],
            device=device,
        )
        empty = flags.numpy() == 1
        if np.any(empty):
            store.release(slots.numpy()[empty])


def _live_keys(store: BlockStore) -> np.ndarray:
    keys = store.slot_keys.numpy()[: store.num_blocks]
    return keys[keys != EMPTY_KEY]
