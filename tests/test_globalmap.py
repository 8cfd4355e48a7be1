"""GlobalMap: full merge, incremental add, undo/redo after pose changes, against references."""

import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj

from . import reference as ref
from .submap_helpers import random_pose, random_vog, reference_merge, reference_values


def as_dict(gmap):
    keys, sums, counts = gmap.sums()
    return {tuple(k): (int(s), int(c)) for k, s, c in zip(keys.tolist(), sums, counts)}


def assert_same_map(a, b):
    ka, sa, ca = a.sums()
    kb, sb, cb = b.sums()
    assert np.array_equal(ka, kb) and np.array_equal(sa, sb) and np.array_equal(ca, cb)
    assert np.array_equal(a.voxels()[1], b.voxels()[1])


def test_merge_matches_brute_force_pull():
    rng = np.random.default_rng(0)
    vog = random_vog(rng, 3)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    expected = reference_merge(vog)
    assert len(expected) > 1000
    assert as_dict(gmap) == expected
    assert max(c for _, c in expected.values()) >= 2  # overlapping submaps were summed


def test_virtual_map_matches_brute_force_sum():
    rng = np.random.default_rng(1)
    vog = random_vog(rng, 3)
    near = [vog.submap(i).voxels()[0][::5] @ vog.pose(i)[:3, :3].T + vog.pose(i)[:3, 3] for i in range(3)]
    near = np.concatenate(near)
    points = np.concatenate([rng.uniform(-4, 4, (1000, 3)), near + rng.uniform(-0.2, 0.2, near.shape)])
    expected = reference_values(vog, points)
    observed = ~np.isnan(expected)
    assert observed.sum() > 300
    np.testing.assert_array_equal(vog.log_odds(points), np.nan_to_num(expected, nan=0.0))
    np.testing.assert_array_equal(vog.state(points), vj.maps.blockmap.classify(expected, vog.config))


def test_global_and_virtual_agree_at_voxel_centres_and_along_rays():
    rng = np.random.default_rng(2)
    vog = random_vog(rng, 4)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    keys, _, _ = gmap.sums()
    centres = (np.concatenate([keys, keys + rng.integers(-2, 3, keys.shape)]) + 0.5) * vog.config.voxel_size
    np.testing.assert_array_equal(gmap.log_odds(centres), vog.log_odds(centres))
    np.testing.assert_array_equal(gmap.state(centres), vog.state(centres))
    origins, directions = rng.uniform(-2, 2, (3000, 3)), rng.normal(size=(3000, 3))
    a, b = gmap.raycast(origins, directions, 5.0), vog.raycast(origins, directions, 5.0)
    for name in ("hit", "distance", "num_unknown", "num_free"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert 0.1 < a.hit.mean() < 0.9
    starts, ends = rng.uniform(-3, 3, (200, 3)), rng.uniform(-3, 3, (200, 3))
    la, lb = gmap.line_query(starts, ends), vog.line_query(starts, ends)
    np.testing.assert_array_equal(la[1], lb[1])
    np.testing.assert_array_equal(la[0], lb[0])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), steps=st.lists(st.sampled_from(["move", "add", "back"]), min_size=1, max_size=5))
def test_any_sequence_of_updates_equals_a_fresh_merge(seed, steps):
    rng = np.random.default_rng(seed)
    vog = random_vog(rng, 2, scans=1, beams=30)
    gmap = vj.GlobalMap(vog.config)
    gmap.add(vog, [0, 1])
    for step in steps:
        if step == "add":
            i = vog.add_submap(random_pose(rng))
            vog.submap(i).integrate_scans(*ref.random_scans(rng, 1, 30, spread=2.0))
            gmap.add(vog, [i])
        else:
            ids = rng.choice(vog.num_submaps, rng.integers(1, vog.num_submaps + 1), replace=False)
            poses = vog.poses(ids)
            if step == "move":
                poses = np.stack([random_pose(rng) for _ in ids])
            else:  # a small correction, as a loop closure makes
                poses[:, :3, 3] += rng.normal(0, 0.05, (len(ids), 3))
            vog.set_poses(ids, poses)
        gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0)
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    assert_same_map(gmap, fresh)
    assert gmap._store.live_blocks == fresh._store.live_blocks


def test_undo_then_redo_at_the_same_pose_is_bit_identical_and_memory_stays_flat():
    rng = np.random.default_rng(3)
    vog = random_vog(rng, 3)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    before = gmap.voxels(), gmap.sums()
    home = vog.pose(1)
    away = home.copy()
    away[:3, 3] += [40.0, 0.0, 0.0]  # far from everything: all its blocks move
    sizes = []
    for _ in range(4):
        vog.set_poses([1], away[None])
        assert gmap.update_poses(vog).reapplied == (1,)
        vog.set_poses([1], home[None])
        assert gmap.update_poses(vog).reapplied == (1,)
        sizes.append((gmap._store.live_blocks, gmap.memory_bytes()))
    after = gmap.voxels(), gmap.sums()
    for x, y in zip(before[0] + before[1], after[0] + after[1]):
        assert np.array_equal(x, y)
    assert len(set(sizes)) == 1  # released blocks are reused: no growth over cycles


def test_thresholds_select_the_submaps_to_reapply():
    rng = np.random.default_rng(4)
    vog = random_vog(rng, 12, scans=1, beams=20)
    # marginals: the first ten set eps_cov (the largest is 2x the base), 11 is far above it
    marginals = np.tile(np.eye(6) * 1e-4, (12, 1, 1))
    marginals[2] *= 2.0
    marginals[4] *= 0.5  # moved, but certain: not re-applied
    marginals[11] *= 10.0
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog, marginals)
    poses = vog.poses()
    poses[3, :3, 3] += [0.001, 0, 0]  # below eps_trans = 2e-3
    poses[4, :3, 3] += [0.01, 0, 0]  # above
    turn = random_pose(np.random.default_rng(0), spread=0)[:3, :3]
    small = np.eye(3)
    angle = 0.005  # below eps_rot = 1e-2
    small[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    poses[5, :3, :3] = small @ poses[5, :3, :3]
    poses[6, :3, :3] = turn @ poses[6, :3, :3]  # a large turn
    poses[11, :3, 3] += [0.5, 0, 0]
    vog.set_poses(np.arange(12), poses)
    report = gmap.update_poses(vog, marginals)
    assert report.moved == (4, 6, 11)
    assert report.uncertain == (11,)
    assert report.reapplied == (11,)
    assert report.eps_cov == pytest.approx(vj.geometry.confidence_volume(marginals[2]))
    report = gmap.update_poses(vog, marginals, eps_cov=0.0)
    assert report.reapplied == (4, 6)  # 11 is already in place
    report = gmap.update_poses(vog)  # no marginals: every moved submap
    assert report.reapplied == () and report.voxels_touched == 0
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    # Submaps 3 and 5 stayed at their applied poses in the global map: they differ from a merge.
    assert as_dict(fresh) != as_dict(gmap)


def test_a_submap_applied_while_uncertain_is_reapplied_when_a_closure_moves_it():
    rng = np.random.default_rng(6)
    vog = random_vog(rng, 12, scans=1, beams=20)
    marginals = np.tile(np.eye(6) * 1e-4, (12, 1, 1))
    marginals[11] *= 10.0  # far from the start, before any loop closure
    gmap = vj.GlobalMap(vog.config)
    gmap.add(vog, range(12), marginals)
    # a loop closure moves submap 11 and makes it as certain as the first ones
    poses = vog.poses()
    poses[11, :3, 3] += [0.3, 0, 0]
    vog.set_poses(np.arange(12), poses)
    marginals[11] = np.eye(6) * 1e-4
    assert gmap.update_poses(vog, marginals).reapplied == (11,)
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    assert as_dict(fresh) == as_dict(gmap)
    # applied now while certain: a further small move is left alone, as Algorithm 1 intends
    poses[11, :3, 3] += [0.01, 0, 0]
    vog.set_poses(np.arange(12), poses)
    report = gmap.update_poses(vog, marginals)
    assert report.moved == (11,) and report.reapplied == ()
    # without marginals the global map cannot know: every submap counts as uncertain
    unknown = vj.GlobalMap(vog.config)
    unknown.merge(vog)
    poses[11, :3, 3] += [0.01, 0, 0]
    vog.set_poses(np.arange(12), poses)
    assert unknown.update_poses(vog, marginals).reapplied == (11,)


def test_a_creeping_submap_with_an_unknown_marginal_counts_as_uncertain():
    rng = np.random.default_rng(8)
    vog = random_vog(rng, 12, scans=1, beams=20)
    certain = np.tile(np.eye(6) * 1e-4, (12, 1, 1))
    applied_uncertain = certain.copy()
    applied_uncertain[7] = np.nan  # its marginal was not computed when it was added
    gmap = vj.GlobalMap(vog.config)
    gmap.add(vog, range(12), applied_uncertain)
    # submap 7 creeps 1.5 mm per update: below eps_trans each time, past it after two
    poses = vog.poses()
    for _ in range(2):
        poses[7, :3, 3] += [0.0015, 0, 0]
        vog.set_poses(np.arange(12), poses)
        marginals = certain.copy()
        marginals[7] = np.nan  # not computed now either: unknown, so uncertain (zero would read certain)
        report = gmap.update_poses(vog, marginals, eps_trans=2e-3)
    assert report.moved == (7,) and report.reapplied == (7,)
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    assert as_dict(fresh) == as_dict(gmap)
    # rows partly NaN are not "unknown": they are damage
    marginals[7, 0, 0] = 1e-4
    with pytest.raises(ValueError, match="marginals"):
        gmap.update_poses(vog, marginals)


def test_queries_during_updates_see_before_or_after_never_half():
    rng = np.random.default_rng(5)
    vog = random_vog(rng, 3, scans=3, beams=80)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    home = vog.pose(0)
    away = home.copy()
    away[:3, 3] += [0.6, -0.4, 0.2]
    keys, _, _ = gmap.sums()
    probes = (keys[::3] + 0.5) * vog.config.voxel_size
    at_home = gmap.log_odds(probes)
    vog.set_poses([0], away[None])
    gmap.update_poses(vog)
    at_away = gmap.log_odds(probes)
    assert not np.array_equal(at_home, at_away)
    seen, stop = [], threading.Event()

    def planner():
        while not stop.is_set():
            seen.append(gmap.log_odds(probes))

    thread = threading.Thread(target=planner)
    thread.start()
    for k in range(400):  # the SLAM side: an update now and then
        vog.set_poses([0], (home if k % 2 == 0 else away)[None])
        gmap.update_poses(vog)
        time.sleep(0.002)
        if len(seen) >= 30 and k >= 20:
            break
    stop.set()
    thread.join()
    assert len(seen) >= 30
    assert all(np.array_equal(s, at_home) or np.array_equal(s, at_away) for s in seen)


def test_save_load_round_trip_keeps_applied_poses(tmp_path):
    rng = np.random.default_rng(6)
    vog = random_vog(rng, 3)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    gmap.save(tmp_path / "global.vog")
    loaded = vj.GlobalMap.load(tmp_path / "global.vog")
    assert_same_map(gmap, loaded)
    assert loaded.applied_ids == (0, 1, 2)
    np.testing.assert_array_equal(loaded.applied_pose(2), vog.pose(2))
    vog.set_poses([2], random_pose(rng)[None])  # the loaded map keeps updating exactly
    loaded.update_poses(vog)
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    assert_same_map(loaded, fresh)
    vj.VoxelMap().save(tmp_path / "voxel.vog")
    with pytest.raises(ValueError, match="not a 'GlobalMap'"):
        vj.GlobalMap.load(tmp_path / "voxel.vog")


@pytest.mark.parametrize(
    "call, argument",
    [
        (lambda g, v: g.update_poses(v, marginals=np.zeros((2, 6, 6))), "marginals"),
        (lambda g, v: g.update_poses(v, marginals=np.zeros((3, 6))), "marginals"),
        (lambda g, v: g.update_poses(v, marginals=np.where(np.eye(6) > 0, np.nan, np.zeros((3, 6, 6)))), "marginals"),
        (lambda g, v: g.update_poses(v, marginals=np.tile(np.triu(np.ones((6, 6))), (3, 1, 1))), "marginals"),
        (lambda g, v: g.update_poses(v, marginals=-np.tile(np.eye(6), (3, 1, 1))), "marginals"),
        (lambda g, v: g.update_poses(v, eps_rot=-1.0), "eps_rot"),
        (lambda g, v: g.update_poses(v, eps_trans=float("nan")), "eps_trans"),
        (lambda g, v: g.update_poses(v, np.tile(np.eye(6), (3, 1, 1)), eps_cov="big"), "eps_cov"),
        (lambda g, v: g.update_poses("not a map"), "vog"),
        (lambda g, v: g.update_poses(vj.VogMap(vj.MapConfig(voxel_size=0.5))), "vog"),
        (lambda g, v: g.add(v, [7]), "ids"),
        (lambda g, v: g.add(v, [0]), "ids"),
        (lambda g, v: g.add(v, ["a"]), "ids"),
        (lambda g, v: g.applied_pose(9), "i"),
    ],
)
def test_bad_input_raises_and_changes_nothing(call, argument):
    rng = np.random.default_rng(7)
    vog = random_vog(rng, 3, scans=1, beams=20)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    vog.set_poses([1], random_pose(rng)[None])
    before = gmap.sums()
    with pytest.raises(ValueError, match=argument):
        call(gmap, vog)
    after = gmap.sums()
    assert all(np.array_equal(x, y) for x, y in zip(before, after))


def test_changed_submap_cannot_be_undone():
    rng = np.random.default_rng(8)
    vog = random_vog(rng, 2, scans=1, beams=20)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    vog.submap(0).integrate_scans(*ref.random_scans(rng, 1, 20))
    vog.set_poses([0], random_pose(rng)[None])
    with pytest.raises(ValueError, match="changed since"):
        gmap.update_poses(vog)


def test_update_with_another_vog_is_refused_and_changes_nothing():
    rng = np.random.default_rng(9)
    vog = random_vog(rng, 3, scans=1, beams=20)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    before = gmap.sums()
    # the same ids and revisions, other submaps: undoing them would corrupt the counts
    impostor = random_vog(np.random.default_rng(9), 3, scans=1, beams=20)
    impostor.set_poses([0], random_pose(rng)[None])
    with pytest.raises(ValueError, match="vog holds other submaps"):
        gmap.update_poses(impostor, eps_rot=0.0, eps_trans=0.0)
    assert all(np.array_equal(a, b) for a, b in zip(before, gmap.sums()))


def test_eps_move_reapplies_only_submaps_whose_voxels_moved_that_far():
    rng = np.random.default_rng(10)
    vog = random_vog(rng, 4, scans=1, beams=20)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    poses = vog.poses()
    poses[1, :3, 3] += [0.01, 0.0, 0.0]  # every voxel 1 cm: below 5 cm
    lo, hi = vog.submap(2).bounds()
    lever = np.abs(np.stack([lo, hi])).max()
    turn = 0.08 / lever  # a small turn, but its farthest corner travels more than 5 cm
    poses[2, :3, :3] = poses[2, :3, :3] @ np.array(
        [[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1.0]]
    )
    vog.set_poses(np.arange(4), poses)
    report = gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0, eps_move_m=0.05)
    assert report.moved == (2,) and report.reapplied == (2,)
    # what the map holds is a merge at the poses last applied
    expected = vj.GlobalMap(vog.config)
    applied = vog.poses()
    applied[1] = gmap.applied_pose(1)
    expected.merge(vog.view(poses=applied))
    assert as_dict(expected) == as_dict(gmap)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), eps_move=st.sampled_from([0.0, 0.05]))
def test_marginals_of_the_moved_submaps_alone_give_the_same_update(seed, eps_move):
    """moved_submaps is update_poses's S1: with NaN for every other submap beyond the first ten,
    the same submaps are re-applied, with the same volumes kept, as with every marginal."""
    rng = np.random.default_rng(seed)
    n = 14
    vog = random_vog(rng, n, scans=1, beams=20)
    marginals = np.tile(np.eye(6), (n, 1, 1)) * rng.uniform(1e-5, 1e-3, (n, 1, 1))
    full, partial = vj.GlobalMap(vog.config), vj.GlobalMap(vog.config)
    full.merge(vog, marginals)
    partial.merge(vog, marginals)
    poses = vog.poses()
    for i in rng.choice(n, 6, replace=False):
        poses[i, :3, 3] += rng.normal(0, 0.05, 3)
    vog.set_poses(np.arange(n), poses)
    later = marginals * rng.uniform(0.2, 3.0, (n, 1, 1))
    moved = partial.moved_submaps(vog, eps_move_m=eps_move)
    sparse = np.full_like(later, np.nan)
    wanted = sorted(set(moved) | set(range(10)))
    sparse[wanted] = later[wanted]
    a = full.update_poses(vog, later, eps_move_m=eps_move)
    b = partial.update_poses(vog, sparse, eps_move_m=eps_move)
    assert a.moved == b.moved == moved
    assert a.reapplied == b.reapplied
    assert as_dict(full) == as_dict(partial)
    assert [full._applied[i].volume for i in full.applied_ids] == [
        partial._applied[i].volume for i in partial.applied_ids
    ]
