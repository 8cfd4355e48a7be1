"""Global-map accumulation: CPU threads split the rows into phases whose threads write disjoint
global blocks; every split gives the same bits as one thread and as the brute-force pull."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax.maps import parallel

from .submap_helpers import random_pose, random_vog, reference_merge


def as_dict(gmap):
    keys, sums, counts = gmap.sums()
    return {tuple(k): (int(s), int(c)) for k, s, c in zip(keys.tolist(), sums, counts)}


def test_threaded_merge_add_and_update_equal_one_thread_and_the_reference(monkeypatch):
    rng = np.random.default_rng(21)
    vog = random_vog(rng, 8, scans=3)
    monkeypatch.setattr(parallel, "MIN_ITEMS_PER_PART", 8)  # split even small launches
    threaded = vj.GlobalMap(vog.config)
    threaded.merge(vog)
    assert as_dict(threaded) == reference_merge(vog)
    moved = vog.poses()
    moved[:4] = [random_pose(rng) for _ in range(4)]
    vog.set_poses(np.arange(8), moved)
    threaded.update_poses(vog)
    monkeypatch.setattr(parallel, "MIN_ITEMS_PER_PART", 10**9)
    single = vj.GlobalMap(vog.config)
    single.merge(vog)
    assert as_dict(threaded) == as_dict(single) == reference_merge(vog)
    assert np.array_equal(threaded.voxels()[1], single.voxels()[1])


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(0, 400), parts=st.integers(1, 8), width=st.integers(1, 40))
def test_disjoint_order_phases_never_share_a_block(seed, count, parts, width):
    rng = np.random.default_rng(seed)
    lo = rng.integers(-width, width, (count, 2))
    spans = np.stack([lo, lo + rng.integers(0, 4, (count, 2))], axis=2)  # (N, axis, lo/hi)
    order, phases = parallel.disjoint_order(spans, parts)
    assert sorted(order.tolist()) == list(range(count))
    covered = []
    for phase in phases[:-1]:
        blocks = []
        for lo_, hi_ in phase:
            covered.extend(range(lo_, hi_))
            cells = set()
            for i in order[lo_:hi_]:
                (x0, x1), (y0, y1) = spans[i]
                cells |= {(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)}
            blocks.append(cells)
        for a in range(len(blocks)):
            for b in range(a + 1, len(blocks)):
                assert not blocks[a] & blocks[b]
    (last,) = phases[-1]
    covered.extend(range(*last))
    assert sorted(covered) == list(range(count))
    assert last[1] - last[0] <= count  # what is left runs on one thread
