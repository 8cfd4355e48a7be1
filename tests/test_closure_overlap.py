"""The closure search's overlap over a complete overlap's score (`[loop_closure] overlap_reference =
"self"`, the lidar preset's): `self_score` against a brute-force sum of the Gaussian blur, the
gate's figure symmetric in the two clouds and near 1 for a cloud that is part of the other, an
unrelated cloud rejected by it, and the papers' "absolute" figure the raw peak score."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from tests.test_slam import structured_cloud
from vogjax import slam
from vogjax.config import CorrelativeConfig, NavNoise
from vogjax.slam.correlative import self_score


def brute_force_self_score(cloud: np.ndarray, resolution_m: float, blur: float) -> float:
    """The cloud's cells on self_score's grid (its corner 2 * 4 sigma + 2 cells below the cloud),
    the blurred occupancy summed cell by cell with the truncated, normalised Gaussian weights
    (ndimage's kernel: radius int(4 sigma + 0.5)), scaled to its maximum, averaged under the
    points."""
    pad = 2 * int(4.0 * blur + 0.5) + 2
    lo = cloud.min(axis=0) - pad * resolution_m
    cells = np.floor((cloud - lo) / resolution_m).astype(int)
    occupied = np.unique(cells, axis=0)
    radius = int(4.0 * blur + 0.5)
    offsets = np.arange(-radius, radius + 1)
    weights = np.exp(-(offsets**2) / (2 * blur**2))
    weights /= weights.sum()

    def field(cell) -> float:
        total = 0.0
        for c in occupied:
            d = cell - c
            if np.all(np.abs(d) <= radius):
                total += np.prod(weights[d + radius])
        return total

    box = [range(occupied[:, a].min() - radius, occupied[:, a].max() + radius + 1) for a in range(3)]
    peak = max(field(np.array(cell)) for cell in itertools.product(*box))
    return float(np.mean([field(cell) for cell in cells]) / peak)


@pytest.mark.parametrize(("seed", "blur"), [(0, 1.0), (1, 0.7)])
def test_self_score_equals_the_brute_force_blur(seed, blur):
    rng = np.random.default_rng(seed)
    # a corner: a floor and a wall, sampled sparsely, plus a few loose points
    floor = np.c_[rng.uniform(0, 1.2, 40), rng.uniform(0, 0.9, 40), np.zeros(40)]
    wall = np.c_[np.zeros(30), rng.uniform(0, 0.9, 30), rng.uniform(0, 0.9, 30)]
    cloud = np.concatenate([floor, wall, rng.uniform(0, 1.2, (5, 3))]) + [3.0, -2.0, 1.0]
    config = CorrelativeConfig(resolution_m=0.3, blur_voxels=blur)
    expected = brute_force_self_score(cloud, 0.3, blur)
    assert self_score(cloud, config) == pytest.approx(expected, rel=1e-5)
    assert 0 < expected < 1  # points on planes get only part of the densest cell's blur


def test_self_score_refuses_bad_clouds_by_name():
    for bad in (np.zeros((0, 3)), np.zeros((4, 2)), np.array([[0.0, np.nan, 0.0]])):
        with pytest.raises(ValueError, match="cloud"):
            self_score(bad)


def _detect(source, target, config):
    """One pair, source = submap 2, target = submap 0, at their true relative pose (the identity),
    the navigation sure of it within centimetres."""
    bounds = [(c.min(axis=0) - 0.1, c.max(axis=0) + 0.1) for c in (target, target[:1], source)]
    poses = np.stack([np.eye(4)] * 3)
    poses[1, :3, 3] = [50.0, 0.0, 0.0]  # far away: not a candidate
    detector = slam.LoopClosureDetector(NavNoise(sigma2_x=1e-4, sigma2_y=1e-4, sigma2_yaw=1e-6), config)
    return detector.detect(2, [target, target[:1], source], bounds, poses, poses, np.array([0.0, 1.0, 2.0]))


def test_the_self_referenced_overlap_is_symmetric_and_near_one_for_a_part_of_the_other():
    rng = np.random.default_rng(4)
    room = structured_cloud(rng, 4000)
    half = room[room[:, 0] < 3.0]  # a short submap: part of what the long one saw
    # (ICP's fitness is not this test's: the long cloud's points off the short one's surfaces raise it)
    free = slam.IcpConfig(free="yaw")
    config = slam.LoopClosureConfig(overlap_reference="self", min_overlap_score=0.5, icp=free, max_fitness_m2=1.0)
    long_on_short, short_on_long = _detect(room, half, config), _detect(half, room, config)
    assert [(c.i, c.k) for c in long_on_short[0]] == [(0, 2)]
    assert [(c.i, c.k) for c in short_on_long[0]] == [(0, 2)]
    a, b = long_on_short[0][0].overlap, short_on_long[0][0].overlap
    assert a == pytest.approx(b, abs=0.02)  # either cloud as the source: the same figure, to the grid
    assert a > 0.9  # every point of the half lies on the room's surfaces
    # the papers' figure is the raw peak score, the long cloud's points half off the short one's
    absolute = slam.LoopClosureConfig(min_overlap_score=0.0, icp=free, max_fitness_m2=1.0)
    raw = _detect(room, half, absolute)[0][0].overlap
    match = slam.correlative_xyh(room, half, np.eye(4), 0.0, 0.0, absolute.correlative)
    assert match.score <= raw < 0.5 * a  # the peak: at least the true pose's score


def test_an_unrelated_cloud_fails_the_self_referenced_overlap_with_its_figure():
    rng = np.random.default_rng(5)
    room = structured_cloud(rng, 3000)
    clutter = rng.uniform(0, 5, (3000, 3))
    config = slam.LoopClosureConfig(overlap_reference="self", min_overlap_score=0.5)
    accepted, rejected = _detect(room, clutter, config)
    assert not accepted and [r.reason for r in rejected] == ["overlap"]
    assert rejected[0].value < 0.5 and rejected[0].limit == 0.5


def test_self_scores_kept_across_detections_give_the_same_closures(monkeypatch):
    """A detector scores each cloud once (by its values) however often it is a candidate, and
    finds what a fresh detector finds each time; a cloud whose values change is scored again."""
    from vogjax.slam import loop_closure

    rng = np.random.default_rng(6)
    room = structured_cloud(rng, 3000)
    clouds = [room, room[:1], room[room[:, 0] < 3.0], room[:1], room[room[:, 1] < 3.0]]
    bounds = [(c.min(axis=0) - 0.1, c.max(axis=0) + 0.1) for c in clouds]
    poses = np.stack([np.eye(4)] * len(clouds))
    poses[[1, 3], :3, 3] = [50.0, 0.0, 0.0]  # far away: never candidates
    times = np.arange(len(clouds), dtype=float)
    noise = NavNoise(sigma2_x=1e-4, sigma2_y=1e-4, sigma2_yaw=1e-6)
    config = slam.LoopClosureConfig(
        overlap_reference="self", min_overlap_score=0.5, icp=slam.IcpConfig(free="yaw"), max_fitness_m2=1.0
    )
    scored = []
    real = loop_closure.self_score
    monkeypatch.setattr(loop_closure, "self_score", lambda cloud, cfg: scored.append(len(cloud)) or real(cloud, cfg))
    keeping = slam.LoopClosureDetector(noise, config)

    def figures(found):
        return [(c.i, c.k, c.overlap, c.T_i_k.tobytes()) for c in found[0]], [(r.i, r.k, r.value) for r in found[1]]

    for k, moved, scores in ((2, False, 2), (4, False, 1), (4, True, 1)):
        if moved:  # the target shared by every call: its values moved by a micrometre
            clouds[0] = clouds[0] + 1e-6
        found = keeping.candidates(k, clouds, bounds, poses)
        assert 0 in found
        before = len(scored)
        kept = keeping.detect(k, clouds, bounds, poses, poses, times)
        assert len(scored) - before == scores  # only the clouds it has not scored yet
        fresh = slam.LoopClosureDetector(noise, config).detect(k, clouds, bounds, poses, poses, times)
        assert len(scored) - before - scores == 1 + len(found)  # the source and every target
        assert figures(kept) == figures(fresh) and kept[0]
