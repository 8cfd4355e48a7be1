"""The coarse levels a block map keeps beside its level-0 blocks (`kernels/levels.py`).

Level k (1 <= k <= MAX_LEVEL) is a BlockStore of its own, of voxels 2^k times the map's edge,
each holding the maximum log-odds of its observed level-0 voxels (NaN: none observed), so the
queries of level 0 run on it unchanged with the voxel size scaled by 2^k. A map builds a level
the first time it is queried and from then on keeps every level it built current.

Keeping them current: each write notes the level-0 blocks it wrote (`note`, a list of keys:
nothing else), and the next coarse query first recomputes, level by level, the coarse blocks
above every block noted since, from their children (`flush`), so a query always sees every
write before it, and the scans integrated between two queries share one recomputation. A log
grown past FLUSH_KEYS keys is flushed by the write itself. A coarse block with no observed
voxel left is released, so a level holds the blocks a fresh build would, whatever happened
before.

A level passes up only the blocks whose voxels changed (fill_coarse_blocks reports it, bit for
bit): a block whose maximum stayed gives its parent nothing new, so the next level recomputes
fewer blocks, and once none changed the levels above are left as they are, launches and all. A
scan mostly lowers free voxels or raises occupied ones already at the maximum, so an update
after every scan usually stops after a level or two. (On a GPU, where reading the flags back
waits for the launch, a map that never releases blocks recomputes every level above the noted
blocks, as it would without them.)

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
# Noted block keys a map holds before a write recomputes its levels itself (8 MiB of keys).
FLUSH_KEYS = 1 << 20


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


def parent_keys(keys: np.ndarray) -> np.ndarray:
    """Distinct packed keys (K,) of the blocks one level up from packed block keys `keys`."""
    if len(keys) == 0:
        return np.zeros(0, np.int64)
    return np.unique(pack_blocks(unpack_blocks(keys) >> 1))


class Levels:
    """The coarse levels 1..count of one map, on its device.

    releases: whether a level-0 voxel can go back to unobserved (a GlobalMap's can; a
    VoxelMap's cannot), so that coarse blocks may empty and must be checked for release.
    """

    def __init__(self, device, releases: bool = True):
        self.device = device
        self.releases = releases
        self.stores: list[BlockStore] = []
        self._keys: list[np.ndarray] = []  # per level, its blocks' packed keys, sorted (a host mirror)
        self._noted: list[np.ndarray] = []
        self._noted_keys = 0

    @property
    def count(self) -> int:
        """The coarsest level kept (0: none)."""
        return len(self.stores)

    @property
    def stale(self) -> bool:
        """Whether writes were noted that the levels do not show yet."""
        return bool(self._noted)

    def store(self, level: int) -> BlockStore:
        return self.stores[level - 1]

    def memory_bytes(self) -> int:
        return sum(store.memory_bytes() for store in self.stores)

    def extend(self, base: BlockStore, level: int) -> None:
        """Build levels count+1 .. `level` from scratch (each from the one below)."""
        self.flush(base)
        while self.count < level:
            below = self.stores[-1] if self.stores else base
            store = BlockStore(self.device, LAYERS)
            self.stores.append(store)
            self._keys.append(np.zeros(0, np.int64))
            self._recompute(self.count, below, parent_keys(_live_keys(below)))

    def rebuild(self, base: BlockStore) -> None:
        """Every kept level from scratch (after the level-0 store was replaced)."""
        count = self.count
        self.stores, self._keys = [], []
        self._noted, self._noted_keys = [], 0
        self.extend(base, count)

    def note(self, base: BlockStore, keys: np.ndarray) -> None:
        """Record that the level-0 blocks with packed keys `keys` (any order, repeats allowed,
        released blocks included) were written; recomputed at the next `flush`."""
        if not self.stores or len(keys) == 0:
            return
        self._noted.append(np.asarray(keys, np.int64))
        self._noted_keys += len(keys)
        if self._noted_keys > FLUSH_KEYS:
            self.flush(base)

    def flush(self, base: BlockStore) -> None:
        """Recompute, in every kept level, the coarse blocks above the blocks noted since."""
        if not self._noted:
            return
        changed = np.unique(np.concatenate(self._noted))
        self._noted, self._noted_keys = [], 0
        changed = changed[changed != EMPTY_KEY]
        below = base
        for level, store in enumerate(self.stores, start=1):
            if len(changed) == 0:
                return
            changed = self._recompute(level, below, parent_keys(changed))
            below = store

    def _recompute(self, level: int, below: BlockStore, keys: np.ndarray) -> np.ndarray:
        """Recompute the coarse blocks `keys` (distinct, sorted) of `level` from `below`;
        release those left empty. Returns the keys of the blocks whose voxels changed (all of
        `keys` where the flags are not read back)."""
        if len(keys) == 0:
            return keys
        device, store = self.device, self.store(level)
        # an update after every scan recomputes a few blocks a level, where the host's fixed
        # costs (arrays made, a launch's arguments) outweigh the kernel: on a CPU the kernel reads
        # the host's keys in place (it has finished when the launch returns), the launch is one
        # call unless the blocks are many, and the host mirror is searched, not set-compared
        d_keys = wp.array(keys, dtype=wp.int64, device=device, copy=device.is_cuda)
        kept = self._keys[level - 1]
        known = np.zeros(len(keys), bool)
        if len(kept):
            known = kept[np.minimum(np.searchsorted(kept, keys), len(kept) - 1)] == keys
        if not known.all():  # the host mirror spares a launch and a read-back when every block exists
            new = keys[~known]
            store.ensure_blocks(wp.array(new, dtype=wp.int64, device=device))
            self._keys[level - 1] = kept = np.union1d(kept, new)
        flags = wp.empty(len(keys) * 8, dtype=wp.int32, device=device)

        def fill(part: int, lo: int, hi: int) -> None:
            whole = hi - lo == len(keys)
            wp.launch(
                levels.fill_coarse_blocks,
                dim=(hi - lo) * 8,
                inputs=[
                    d_keys if whole else d_keys[lo:hi],
                    store.table_keys,
                    store.table_slots,
                    below.table_keys,
                    below.table_slots,
                    below.layers["log_odds"],
                ],
                outputs=[store.layers["log_odds"], flags if whole else flags[lo * 8 : hi * 8]],
                device=device,
            )

        parallel.split_launch(fill, len(keys), parallel.num_parts(device, len(keys) * 64))
        if not (self.releases or not device.is_cuda):
            return keys
        octants = flags.numpy().reshape(-1, 8)
        if self.releases:
            empty = ~(octants & levels.OCTANT_OBSERVED).any(axis=1)
            if np.any(empty):
                store.release(store.find(d_keys).numpy()[empty])
                self._keys[level - 1] = np.setdiff1d(kept, keys[empty], assume_unique=True)
        return keys[(octants & levels.OCTANT_CHANGED).any(axis=1)]


def _live_keys(store: BlockStore) -> np.ndarray:
    keys = store.slot_keys.numpy()[: store.num_blocks]
    return keys[keys != EMPTY_KEY]
