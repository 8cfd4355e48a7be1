"""Hash table and block pool growth: nothing is dropped, every key keeps its own slot."""

import numpy as np
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax import devices
from vogjax.maps.blocks import BlockStore, pack_blocks, unpack_blocks


def test_pack_round_trip_at_the_limits():
    lim = 1 << 20
    blocks = np.array([[-lim, -lim, -lim], [lim - 1, lim - 1, lim - 1], [0, -1, 5], [-7, 3, lim - 1]])
    np.testing.assert_array_equal(unpack_blocks(pack_blocks(blocks)), blocks)
    assert np.all(pack_blocks(blocks) >= 0)  # never the empty marker


def test_table_grows_past_millions_of_blocks():
    devices.init()
    device = wp.get_device("cpu")
    store = BlockStore(device, layers={})  # keys only: the pool is not what is tested here
    rng = np.random.default_rng(0)
    blocks = np.unique(rng.integers(-3000, 3000, (2_600_000, 3)), axis=0)
    rng.shuffle(blocks)
    keys = pack_blocks(blocks)
    for chunk in np.array_split(keys, 5):
        # Each chunk repeats some keys of its own and of earlier chunks.
        with_repeats = np.concatenate([chunk, chunk[:1000], keys[:500]])
        store.ensure_blocks(wp.array(with_repeats, dtype=wp.int64, device=device))
    assert store.num_blocks == len(keys) > 2_000_000
    assert store.table_capacity >= 2 * store.num_blocks
    slots = store.find(wp.array(keys, dtype=wp.int64, device=device)).numpy()
    assert np.array_equal(np.sort(slots), np.arange(len(keys)))
    np.testing.assert_array_equal(store.slot_keys.numpy()[slots], keys)
    absent = pack_blocks(np.array([[5000, 0, 0], [0, -5000, 0]]))
    assert store.find(wp.array(absent, dtype=wp.int64, device=device)).numpy().tolist() == [-1, -1]


def test_map_grows_its_pool_and_keeps_values():
    # Long beams in every direction: each scan adds thousands of blocks, so the pool and the
    # table grow between scans. The result must equal one batch that grows only once.
    rng = np.random.default_rng(1)
    cfg = vj.MapConfig(voxel_size=0.1, max_range=20.0)
    directions = rng.normal(size=(3000, 3))
    points = 18.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    scan = np.repeat(np.arange(3), 1000)
    origins = np.array([[0.0, 0.0, 0.0], [9.0, 0.0, 0.0], [0.0, 9.0, 0.0]])
    points += origins[scan]
    gradual = vj.VoxelMap(cfg)
    sizes = []
    for s in range(3):
        gradual.integrate_scan(origins[s], points[scan == s])
        sizes.append((gradual.num_blocks, gradual.memory_bytes()))
    assert sizes[0][0] > 5000 and sizes[2][0] > 2 * sizes[0][0] and sizes[2][1] > sizes[0][1]
    at_once = vj.VoxelMap(cfg)
    at_once.integrate_scans(origins, points, scan)
    a, b = gradual.voxels(), at_once.voxels()
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert gradual.memory_bytes() >= gradual.num_blocks * 512 * 4


@settings(max_examples=25, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["numpy", "warp", "release"]),
            st.lists(st.integers(-40, 40), min_size=0, max_size=300),
        ),
        min_size=1,
        max_size=12,
    )
)
def test_small_allocations_and_releases_match_a_set(steps):
    # Many small calls (the replayed launches' case: each reuses or re-records its launch as
    # the table and pool grow) against a plain set of keys: every live key has its own slot,
    # holding its key, and nothing else is found.
    devices.init()
    device = wp.get_device("cpu")
    store = BlockStore(device, layers={"v": (wp.float32, 0.0)}, block_capacity=1)
    live: set[int] = set()
    for kind, coordinates in steps:
        blocks = np.array(coordinates[: len(coordinates) // 3 * 3], dtype=np.int64).reshape(-1, 3)
        keys = pack_blocks(blocks)
        if kind == "release":
            gone = sorted(live & set(keys.tolist()))
            slots = store.find(wp.array(np.array(gone, np.int64), dtype=wp.int64, device=device)).numpy()
            store.release(slots)
            live -= set(gone)
        else:
            store.ensure_blocks(keys if kind == "numpy" else wp.array(keys, dtype=wp.int64, device=device))
            live |= set(keys.tolist())
        every = pack_blocks(np.array(np.meshgrid(*[np.arange(-13, 14)] * 3)).reshape(3, -1).T)
        slots = store.find(wp.array(every, dtype=wp.int64, device=device)).numpy()
        inside = np.isin(every, np.array(sorted(live), np.int64))
        assert np.all(slots[~inside] == -1)
        assert np.all(slots[inside] >= 0) and len(np.unique(slots[inside])) == inside.sum()
        np.testing.assert_array_equal(store.slot_keys.numpy()[slots[inside]], every[inside])
