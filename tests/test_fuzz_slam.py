"""Fuzzing the SLAM backend (issue 17): PoseGraph, icp / icp_batch and the correlative search.

Valid and hostile arguments; each call returns a well-formed (and, where a reference is cheap,
correct) result or raises ValueError naming the argument, leaving the graph as it was. A pose
graph is checked against a twin that only ever receives the calls the fuzzed one accepted.
Helpers and settings: tests/test_fuzz_maps.py.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import vogjax as vj
from vogjax import devices, slam
from vogjax.config import CorrelativeConfig, IcpConfig
from vogjax.geometry import exp_se3, log_se3
from vogjax.slam import backend, correlative

from .test_fuzz_maps import JUNK, REFUSED, SPECIALS, attempt, combined, fuzz, poses, refuses

DEVICE = str(devices.resolve(None))  # the front end's kernels, on the GPU where there is one

# ------------------------------------------------------------------------------ PoseGraph

DURATIONS = st.sampled_from(
    [
        0.1,
        1.0,
        20.0,
        1e3,
        1e7,
        1e-3,  # valid
        1e-5,
        0.0,
        -1.0,
        math.nan,
        math.inf,
        1.1e7,
        "1",
        None,
        True,
        [1.0],
        np.array([1.0]),
    ]
)


def duration_valid(value) -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return "invalid"
    return "valid" if math.isfinite(value) and backend.MIN_DURATION_S <= value <= backend.MAX_DURATION_S else "invalid"


def step_valid(previous, pose, duration, noise) -> str:
    """A step of more drift sigmas in x or y (in the previous pose's frame) than the pose graph
    weighs may be refused; smaller ones must be taken."""
    step = (np.linalg.inv(previous) @ pose)[:2, 3]
    sigmas = np.abs(step) / np.sqrt(np.array([noise.sigma2_x, noise.sigma2_y]) * duration)
    return "valid" if sigmas.max() <= 1e6 else "either"


def covariance_case(draw):
    """(value, expectation) of a (6,6) loop-closure covariance."""
    rng = np.random.default_rng(draw(st.integers(0, 1000)))
    q, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    low, high = draw(st.sampled_from([(1e-4, 1e-2), (1e-12, 1e-12), (1e12, 1e12), (1e-12, 1e12), (1e-3, 1.0)]))
    good = q @ np.diag(np.geomspace(low, high, 6)) @ q.T
    good = (good + good.T) / 2
    kind = draw(
        st.sampled_from(["valid"] * 4 + ["asym", "negative", "singular", "tiny", "huge", "special", "shape", "junk"])
    )
    if kind == "valid":
        return good, "either" if high / low > 1e15 else "valid"  # symmetric to 1e-9 relative only
    if kind == "asym":
        good[0, 1] += abs(good).max() * 1e-3
        return good, "invalid"
    if kind == "negative":
        return -good, "invalid"
    if kind == "singular":
        return np.zeros((6, 6)), "invalid"
    if kind == "tiny":
        return np.eye(6) * 1e-14, "invalid"
    if kind == "huge":
        return np.eye(6) * 1e14, "invalid"
    if kind == "special":
        good[2, 2] = draw(st.sampled_from(SPECIALS))
        return good, "invalid"
    if kind == "shape":
        return np.eye(draw(st.sampled_from([3, 5, 7]))), "invalid"
    return draw(st.sampled_from([j for j in JUNK if not isinstance(j, (list, tuple))] + [[1.0] * 6])), "invalid"


def basis_case(draw):
    kind = draw(st.sampled_from(["none"] * 4 + ["valid", "valid", "r0", "r7", "skew", "special", "junk"]))
    if kind == "none":
        return None, "valid"
    r = draw(st.integers(1, 6))
    q, _ = np.linalg.qr(np.random.default_rng(draw(st.integers(0, 99))).normal(size=(6, 6)))
    if kind == "valid":
        return q[:, :r], "valid"
    if kind == "r0":
        return np.zeros((6, 0)), "invalid"
    if kind == "r7":
        return np.ones((6, 7)), "invalid"
    if kind == "skew":
        return q[:, :r] * 2.0, "invalid"
    if kind == "special":
        bad = q[:, :r].copy()
        bad[0, 0] = math.nan
        return bad, "invalid"
    return draw(st.sampled_from(["basis", [[1, 2], [3]], 3.0])), "invalid"


SUBMAP_IDS = st.one_of(st.integers(-2, 6), st.sampled_from([np.int64(1), np.int32(0), 1.0, "1", None, True, [0]]))


def id_valid(value, n) -> str:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        return "invalid"
    return "valid" if 0 <= value < n else "invalid"


def nav_pose(k: int) -> np.ndarray:
    """The k-th navigation pose of a slow lawnmower-ish track."""
    return exp_se3(np.array([0.01 * k, -0.005 * k, 0.3 * np.sin(k), 1.5 * k, 0.4 * k, -0.1 * k]))


def graph_state(pg):
    return pg.num_submaps, list(pg.factors), pg.navigation_poses(), pg.poses()


@fuzz(40)
@given(data=st.data())
def test_pose_graph(data):
    """add_submap / add_loop_closure / update / marginals with valid and hostile arguments: the
    graph matches a twin that got only the accepted calls (same factors, the same optimised
    poses bit for bit); results are finite rigid poses and symmetric PSD marginals; loop closures
    that agree with the navigation leave the navigation poses where they are."""
    noise = vj.NavNoise()
    pg, twin = slam.PoseGraph(noise), slam.PoseGraph(noise)
    consistent = True  # every factor so far agrees with the navigation poses
    for _ in range(data.draw(st.integers(2, 8))):
        op = data.draw(st.sampled_from(["add", "add", "loop", "loop", "update", "marginals"]))
        snapshot = lambda: graph_state(pg)
        n = pg.num_submaps
        if op == "add":
            pose, e1 = data.draw(poses())
            if e1 == "valid":
                pose = nav_pose(n)
            duration = data.draw(DURATIONS)
            e2 = duration_valid(duration) if n > 0 else "either"  # the first node has no duration
            e3 = (
                step_valid(pg.navigation_poses()[-1], pose, duration, noise)
                if n > 0 and e1 == e2 == "valid"
                else "either"
            )
            i = attempt(
                lambda: pg.add_submap(pose, duration),
                ["T_world_submap_nav", "duration_s"],
                snapshot,
                combined(e1, e2, e3),
                "PoseGraph.add_submap",
            )
            if i is not REFUSED:
                assert i == n
                twin.add_submap(pose, duration)
                consistent &= e1 == "valid"
        elif op == "loop":
            i, k = data.draw(SUBMAP_IDS), data.draw(SUBMAP_IDS)
            T, e3 = data.draw(poses())
            agreeing = data.draw(st.booleans()) and id_valid(i, n) == id_valid(k, n) == "valid"
            if agreeing and e3 == "valid":
                T = np.linalg.inv(pg.navigation_poses()[int(i)]) @ pg.navigation_poses()[int(k)]
            covariance, e4 = covariance_case(data.draw)
            basis, e5 = basis_case(data.draw)
            e_ids = combined(id_valid(i, n), id_valid(k, n))
            if e_ids == "valid" and int(i) == int(k):
                e_ids = "invalid"
            expect = combined(e_ids, e3, e4, e5)
            result = attempt(
                lambda: pg.add_loop_closure(i, k, T, covariance, basis),
                ["i", "k", "T_i_k", "covariance", "basis"],
                snapshot,
                expect,
                "PoseGraph.add_loop_closure",
            )
            if result is not REFUSED:
                twin.add_loop_closure(i, k, T, covariance, basis)
                consistent &= agreeing and e3 == "valid"
        elif op == "update":
            optimised = pg.update()
            assert np.array_equal(optimised, twin.update())
            assert optimised.shape == (pg.num_submaps, 4, 4) and np.all(np.isfinite(optimised))
            rotations = optimised[:, :3, :3]
            assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-6)
            if consistent and pg.num_submaps:
                np.testing.assert_allclose(optimised, pg.navigation_poses(), atol=1e-5)
        else:
            ids = data.draw(st.one_of(st.lists(st.integers(-1, 6), max_size=3), SUBMAP_IDS))
            updated = len(pg.poses())
            if isinstance(ids, (bool, str, float)) or ids is None:
                expect = "invalid"
            else:
                array = np.atleast_1d(np.asarray(ids))
                expect = "valid" if array.dtype.kind in "iu" or array.size == 0 else "invalid"
                if expect == "valid" and array.size and not (array.min() >= 0 and array.max() < updated):
                    expect = "invalid"
            marginals = attempt(lambda: pg.marginals(ids), ["ids"], snapshot, expect, "PoseGraph.marginals")
            if marginals is not REFUSED:
                count = np.atleast_1d(np.asarray(ids)).size
                assert marginals.shape == (count, 6, 6) and np.all(np.isfinite(marginals))
                assert np.allclose(marginals, marginals.transpose(0, 2, 1), rtol=1e-6, atol=1e-12)
                assert np.all(np.linalg.eigvalsh(marginals) > -1e-9 * np.abs(marginals).max(initial=1.0))
        assert pg.factors == twin.factors and pg.num_submaps == twin.num_submaps


@fuzz(25)
@given(data=st.data())
def test_pose_graph_constructor(data):
    prior, e1 = data.draw(poses())
    if prior is None:
        e1 = "valid"  # the default: the identity
    kind = data.draw(st.sampled_from(["default", "valid", "tiny", "huge", "shape", "special", "junk", "negative"]))
    sigmas, e2 = {
        "default": (backend.PRIOR_SIGMAS, "valid"),
        "valid": (np.full(6, 0.5), "valid"),
        "tiny": (np.full(6, 1e-7), "invalid"),
        "huge": (np.full(6, 1e7), "invalid"),
        "shape": (np.ones(5), "invalid"),
        "special": (np.r_[np.ones(5), math.nan], "invalid"),
        "junk": ("sigmas", "invalid"),
        "negative": (np.full(6, 1e-3), "valid"),
    }[kind]  # see below
    pg = attempt(
        lambda: slam.PoseGraph(vj.NavNoise(), prior, sigmas),
        ["prior_pose", "prior_sigmas"],
        None,
        combined(e1, e2),
        "PoseGraph",
    )
    if pg is not REFUSED:
        pg.add_submap(np.eye(4) if prior is None else prior)
        expected = np.eye(4) if prior is None else np.asarray(prior, np.float64).reshape(4, 4)
        np.testing.assert_allclose(pg.update()[0], expected, atol=1e-9)


# ------------------------------------------------------------------------------ ICP


def structured_cloud(rng, count=300, offset=(0.0, 0.0, 0.0)):
    """Points on three orthogonal rough planes: every direction constrained."""
    a, b, c = (rng.uniform(0, 2, (count // 3, 2)) for _ in range(3))
    planes = [
        np.c_[a[:, 0], a[:, 1], 0.02 * np.sin(3 * a[:, 0])],
        np.c_[b[:, 0], 0.02 * np.cos(2 * b[:, 1]), b[:, 1]],
        np.c_[0.02 * np.sin(c[:, 1] * 4), c[:, 0], c[:, 1]],
    ]
    return np.concatenate(planes) + offset


def cloud_case(draw, good, junk: bool = True, min_points: int = 3, huge=(1e3, 1e8, 1e100, 1e150)):
    kind = draw(st.sampled_from(["valid"] * 5 + ["few", "special", "shape", "junk", "empty", "huge", "tiny"]))
    if kind == "valid":
        return good, "valid"
    if kind == "few":
        return good[:2], "invalid" if min_points > 2 else "valid"
    if kind == "special":
        bad = good.copy()
        bad[draw(st.integers(0, len(bad) - 1)), draw(st.integers(0, 2))] = draw(st.sampled_from(SPECIALS))
        return bad, "invalid"
    if kind == "shape":
        return good[:, :2], "invalid"
    if kind == "empty":
        return np.zeros((0, 3)), "invalid"
    if kind == "huge":  # far away or enormous (beyond 1e150: test_huge_clouds_are_refused_or_aligned)
        return good * draw(st.sampled_from(huge)), "either"
    if kind == "tiny":
        return good * draw(st.sampled_from([1e-6, 1e-150, 1e-310])), "either"
    if not junk:
        return good[:, :1], "invalid"
    return draw(st.sampled_from(JUNK)), "invalid"


def well_formed_icp(result, source_count):
    T = result.T_target_source
    assert T.shape == (4, 4) and np.all(np.isfinite(T)), "T_target_source not finite"
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6) and np.array_equal(T[3], [0, 0, 0, 1])
    assert 0 <= result.num_inliers <= source_count
    assert result.fitness >= 0  # inf when nothing matched; never NaN
    assert result.hessian.shape == (6, 6) and result.eigenvalues.shape == (6,)
    assert result.basis.shape[0] == 6 and result.basis.shape[1] <= 6
    if result.converged:
        assert np.isfinite(result.fitness) and np.all(np.isfinite(result.hessian))


@fuzz(40)
@given(data=st.data())
def test_icp(data):
    """icp with valid and hostile clouds, poses, methods and settings: a finite rigid result,
    and on clean clouds a small known motion recovered."""
    rng = np.random.default_rng(data.draw(st.integers(0, 50)))
    target_good = structured_cloud(rng)
    truth = exp_se3(np.r_[rng.normal(size=3) * 0.02, rng.normal(size=3) * 0.05])  # T_target_source
    source_good = (target_good - truth[:3, 3]) @ truth[:3, :3]  # truth^-1 applied
    source, e1 = cloud_case(data.draw, source_good)
    target, e2 = cloud_case(data.draw, target_good)
    T_init, e3 = data.draw(st.one_of(st.just((None, "valid")), poses()))
    if e3 == "valid" and T_init is not None:
        T_init = np.eye(4)
    method = data.draw(st.sampled_from(["point_to_plane"] * 3 + ["point_to_point_xyh", "plane", None, 3]))
    e4 = "valid" if method in ("point_to_plane", "point_to_point_xyh") else "invalid"
    config = IcpConfig(
        max_correspondence_m=data.draw(st.sampled_from([0.5, 1e-9, 1e300])),
        max_iterations=data.draw(st.sampled_from([50, 1, 10_000])),
    )
    result = attempt(
        lambda: slam.icp(source, target, T_init, method, config),
        ["source", "target", "T_init", "method"],
        None,
        combined(e1, e2, e3, e4),
        "icp",
    )
    if result is REFUSED:
        return
    well_formed_icp(result, len(np.asarray(source)))
    on_device = slam.icp_batch([source], [target], None if T_init is None else [T_init], method, config, DEVICE)[0]
    well_formed_icp(on_device, len(np.asarray(source)))
    if e1 == e2 == "valid":  # clouds without ties (tiny ones round distances to ties): the same bits
        assert np.array_equal(on_device.T_target_source, result.T_target_source)
        assert (on_device.iterations, on_device.fitness) == (result.iterations, result.fitness)
    clean = (
        e1 == e2 == e3 == "valid"
        and method == "point_to_plane"
        and config.max_correspondence_m == 0.5
        and config.max_iterations == 50
    )
    if clean:
        assert result.converged
        np.testing.assert_allclose(log_se3(np.linalg.inv(truth) @ result.T_target_source), 0, atol=2e-3)


@fuzz(20)
@given(data=st.data())
def test_icp_batch(data):
    """icp_batch pairs up its lists: mismatched lengths, empty lists and junk are refused; the
    results equal one icp call per pair."""
    rng = np.random.default_rng(data.draw(st.integers(0, 20)))
    clouds = [structured_cloud(rng, 120, offset=rng.normal(size=3)) for _ in range(3)]
    count_s, count_t = data.draw(st.integers(0, 3)), data.draw(st.integers(0, 3))
    assume(count_s or count_t)  # both empty: test_empty_batch_is_fine
    sources, targets = clouds[:count_s], clouds[:count_t][::-1]
    T_inits = data.draw(st.sampled_from([None, "eye", "short", "junk"]))
    inits = {
        None: None,
        "eye": np.tile(np.eye(4), (count_s, 1, 1)),
        "short": np.tile(np.eye(4), (count_s + 1, 1, 1)),
        "junk": "T",
    }[T_inits]
    expect = combined(
        "valid" if count_s == count_t else "invalid", "invalid" if T_inits in ("short", "junk") else "valid"
    )
    results = attempt(
        lambda: slam.icp_batch(sources, targets, inits), ["sources", "targets", "T_inits"], None, expect, "icp_batch"
    )
    if results is REFUSED:
        return
    assert len(results) == count_s
    for s, t, r in zip(sources, targets, results):
        single = slam.icp(s, t, None)
        np.testing.assert_allclose(r.T_target_source, single.T_target_source, atol=1e-9)


# ------------------------------------------------------------------------------ correlative search


def blocky_cloud(rng, resolution=0.1):
    """Occupied voxel centres of a few boxes on a floor: an unambiguous x-y pattern."""
    cells = set()
    for _ in range(5):
        lo = rng.integers(0, 25, 3)
        size = rng.integers(1, 6, 3)
        for x in range(size[0]):
            for y in range(size[1]):
                cells.add((lo[0] + x, lo[1] + y, rng.integers(0, 3)))
    return (np.array(sorted(cells)) + 0.5) * resolution


@fuzz(40)
@given(data=st.data())
def test_correlative_search(data):
    """correlative_xyh with valid and hostile clouds, radii and settings: a rigid result whose
    x-y-yaw correction stays within the radii, and on a clean pair the known whole-voxel shift."""
    rng = np.random.default_rng(data.draw(st.integers(0, 30)))
    target_good = blocky_cloud(rng)
    shift = np.r_[data.draw(st.integers(-8, 8)), data.draw(st.integers(-8, 8)), 0] * 0.1
    source_good = target_good - shift  # T_target_source = translation by `shift`
    # (clouds that are no arrays: see test_junk_clouds_are_refused_naming_the_argument)
    # (clouds beyond 1e8 m: test_huge_search_radii_are_refused_naming_them)
    source, e1 = cloud_case(data.draw, source_good, junk=False, min_points=1, huge=(1e3, 1e8))
    target, e2 = cloud_case(data.draw, target_good, junk=False, min_points=1, huge=(1e3, 1e8))
    if e1 == "either" or e2 == "either":
        e1 = "either"
    T_init, e3 = data.draw(poses())
    clean_init = e3 == "valid"
    if clean_init:
        T_init = np.eye(4)
    radius = data.draw(
        st.sampled_from(
            [1.0, 1.0, 0.0, 3.0, 1e300, -1.0, math.nan, math.inf, "1", None, True, np.float64(1.0), np.int64(1)]
        )
    )
    yaw = data.draw(st.sampled_from([0.0, 0.0, 0.02, 0.5, 1e300, -0.1, math.nan, "0"]))

    def number_valid(value):
        if isinstance(value, (bool, str)) or value is None or isinstance(value, np.integer):
            return "either"
        return "valid" if math.isfinite(value) and value >= 0 else "invalid"

    e4, e5 = number_valid(radius), number_valid(yaw)
    if radius == 1e300 or yaw == 1e300:
        e4 = "either"  # refused as a search too large, naming both radii
        # (with clouds beyond 1e100 or yaw steps of 1e-9: test_huge_search_radii_are_refused_naming_them)
        assume(e1 == e2 == "valid")
    config = data.draw(
        st.sampled_from(
            [
                CorrelativeConfig(),
                CorrelativeConfig(resolution_m=1e-4),
                CorrelativeConfig(yaw_step_rad=1e-9),
                CorrelativeConfig(blur_voxels=0.0),
                CorrelativeConfig(resolution_m=1e3),
            ]
        )
    )
    assume(not (yaw == 1e300 and config.yaw_step_rad < 1e-6))
    e6 = "valid" if config in (CorrelativeConfig(), CorrelativeConfig(blur_voxels=0.0)) else "either"
    match = attempt(
        lambda: slam.correlative_xyh(source, target, T_init, radius, yaw, config),
        ["source", "target", "T_init", "radius_m", "yaw_radius_rad"],
        None,
        combined(e1, e2, e3, e4, e5, e6),
        "correlative_xyh",
    )
    if match is REFUSED:
        return
    T = match.T_target_source
    assert T.shape == (4, 4) and np.all(np.isfinite(T))
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert 0 <= match.score <= 1 + 1e-6 and 0 <= match.runner_up <= match.score + 1e-6
    correction = T @ np.linalg.inv(np.asarray(T_init, np.float64))
    yaw_moved = abs(math.atan2(correction[1, 0], correction[0, 0]))
    assert yaw_moved <= float(yaw) + 1e-9
    # the device's direct correlation peaks where the FFT does, to rounding: at a tie (blocky
    # clouds have many) it may pick the other peak, of the same score
    on_device = slam.correlative_xyh_batch([(source, target, T_init, radius, yaw)], config, DEVICE)[0]
    assert abs(on_device.score - match.score) <= 1e-5 * max(match.score, 1e-2)
    if np.array_equal(on_device.T_target_source, T):
        assert abs(on_device.runner_up - match.runner_up) <= 1e-5 * max(match.runner_up, 1e-2)
    whole = len(source) == len(source_good) and len(target) == len(target_good)
    if (
        e1 == e2 == e3 == e4 == e5 == e6 == "valid"
        and whole
        and float(radius) >= 1.0
        and float(yaw) == 0.0
        and config == CorrelativeConfig()
    ):
        np.testing.assert_allclose(T[:2, 3], shift[:2], atol=1e-9)
        assert T[2, 3] == 0


# ------------------------------------------------------------------------------ findings, fixed (regression tests)


@pytest.mark.parametrize("duration_s", [1e-9, 1e-300])
def test_tiny_durations_are_refused_or_solved(duration_s):
    pg = slam.PoseGraph()
    pg.add_submap(np.eye(4))
    try:
        pg.add_submap(nav_pose(1), duration_s)
    except ValueError as error:
        assert "duration_s" in str(error)
        return
    try:
        poses = pg.update()
    except RuntimeError as error:
        raise AssertionError(f"update raised {type(error).__name__}: {str(error)[:60]}") from None
    assert np.all(np.isfinite(poses))


COMPLEX_POSE = np.eye(4) + 1e-3j


@pytest.mark.parametrize(
    "call",
    [
        lambda: slam.PoseGraph(prior_pose=COMPLEX_POSE),
        lambda: slam.PoseGraph(prior_pose=np.eye(4).astype(str)),
        lambda: slam.PoseGraph(prior_sigmas=np.ones(6) * (1 + 1j)),
        lambda: _three_node_graph().add_loop_closure(0, 2, np.eye(4), np.eye(6) * (1e-2 + 1e-2j)),
        lambda: slam.icp(structured_cloud(np.random.default_rng(0)) + 1j, structured_cloud(np.random.default_rng(0))),
        lambda: slam.correlative_xyh(
            blocky_cloud(np.random.default_rng(0)) + 1j, blocky_cloud(np.random.default_rng(0)), np.eye(4), 1.0, 0.0
        ),
    ],
    ids=[
        "prior_pose-complex",
        "prior_pose-strings",
        "prior_sigmas-complex",
        "covariance-complex",
        "icp-complex",
        "correlative-complex",
    ],
)
def test_complex_and_text_arrays_are_refused(call):
    refuses(call)


def _three_node_graph():
    pg = slam.PoseGraph()
    for k in range(3):
        pg.add_submap(nav_pose(k), 1.0)
    return pg


def test_empty_batch_is_fine():
    try:
        assert slam.icp_batch([], []) == []
    except ValueError as error:
        assert "sources" in str(error), f"{error!r} names no argument"


@pytest.mark.parametrize(
    "call",
    [
        lambda: slam.PoseGraph(prior_pose=np.zeros((0, 4, 4))),
        lambda: _three_node_graph().add_submap(np.zeros((0, 4, 4)), 1.0),
        lambda: _three_node_graph().add_loop_closure(0, 2, np.zeros((0, 4, 4)), np.eye(6) * 1e-2),
    ],
    ids=["prior_pose", "add_submap", "add_loop_closure"],
)
def test_an_empty_pose_stack_is_not_a_pose(call):
    try:
        refuses(call)
    except IndexError as error:
        raise AssertionError(f"IndexError: {error}") from None


def test_negative_prior_sigmas_are_refused_naming_them():
    refuses(lambda: slam.PoseGraph(prior_sigmas=-np.ones(6)), "prior_sigmas")


@pytest.mark.parametrize("scale", [1e154, 1e200])
def test_huge_clouds_are_refused_or_aligned(scale):
    cloud = structured_cloud(np.random.default_rng(0)) * scale
    try:
        result = slam.icp(cloud, cloud)
    except ValueError as error:
        assert "source" in str(error) or "target" in str(error)
        return
    except (IndexError, np.linalg.LinAlgError) as error:
        raise AssertionError(f"{type(error).__name__}: {error}") from None
    assert np.allclose(result.T_target_source, np.eye(4))


@pytest.mark.parametrize("junk", ["abc", {"x": 1}], ids=["text", "dict"])
def test_junk_clouds_are_refused_naming_the_argument(junk):
    try:
        refuses(
            lambda: slam.correlative_xyh(junk, blocky_cloud(np.random.default_rng(0)), np.eye(4), 1.0, 0.0), "source"
        )
    except TypeError as error:
        raise AssertionError(f"TypeError: {error}") from None


def test_far_clouds_are_refused_or_matched():
    cloud = blocky_cloud(np.random.default_rng(1)) + 1e17
    try:
        match = slam.correlative_xyh(cloud, cloud, np.eye(4), 1.0, 0.0)
    except ValueError as error:
        assert "source" in str(error)
        return
    assert np.array_equal(match.T_target_source, np.eye(4)), f"shift {match.T_target_source[:3, 3]}"


@pytest.mark.parametrize(
    "scale, radius_m, yaw_radius_rad, yaw_step_rad",
    [(1e100, 1e300, 0.0, 0.005), (1e100, 1.0, 0.0, 0.005), (1.0, 1.0, 1e300, 1e-9)],
    ids=["far-clouds-huge-radius", "far-source", "yaw"],
)
def test_huge_search_radii_are_refused_naming_them(scale, radius_m, yaw_radius_rad, yaw_step_rad):
    cloud = blocky_cloud(np.random.default_rng(0))
    config = CorrelativeConfig(yaw_step_rad=yaw_step_rad)
    try:
        slam.correlative_xyh(cloud * scale, cloud, np.eye(4), radius_m, yaw_radius_rad, config)
    except ValueError as error:
        assert "radius" in str(error) or "source" in str(error), f"{error!r} names no argument"
        return
    except OverflowError as error:
        raise AssertionError(f"OverflowError: {error}") from None
    raise AssertionError("accepted")


class _Accepted(Exception):
    pass


def test_correlative_search_time_is_bounded(monkeypatch):
    """Accepted searches must be bounded in time: here, no more than 1e9 cell-steps (about 3 min
    of FFTs here). Checked without running the search: the first step after the checks raises."""

    def stop(*args, **kwargs):
        raise _Accepted

    monkeypatch.setattr(correlative.ndimage, "gaussian_filter", stop)
    monkeypatch.setattr(correlative.fft, "rfft2", stop)
    rng = np.random.default_rng(0)
    # a narrow column 4.9 m tall: 50 z layers, and little reach for the yaw steps
    cloud = np.c_[rng.uniform(0, 0.5, (4000, 2)), rng.uniform(0, 4.9, 4000)]
    config = CorrelativeConfig()
    try:  # 44 m: 4.3e7 cells; 3 rad at 5 mrad: 1201 yaw steps
        correlative.correlative_xyh(cloud, cloud, np.eye(4), 44.0, 600 * config.yaw_step_rad, config)
    except ValueError as error:
        assert "radius" in str(error)
        return
    except _Accepted:
        raise AssertionError("a search of about 5e10 cell-steps was accepted") from None
    raise AssertionError("the search ran without reaching its first FFT")


@pytest.mark.parametrize("field", ["min_sigma_translation_m", "min_sigma_rotation_rad"])
def test_loop_closure_floors_stay_within_the_pose_graph_bounds(field):
    from vogjax.config import LoopClosureConfig

    def closure_with_floor():
        floor = getattr(LoopClosureConfig(**{field: 1e7}), field) ** 2
        backend._covariance("covariance", np.eye(6) * 1e-4 + np.diag([floor] * 6), 6)

    refuses(closure_with_floor, field)


def test_a_navigation_jump_the_graph_cannot_weigh_is_refused():
    """3,000 km in 0.1 s: the odometry factor's information swamps the graph and iSAM2 raised
    GTSAM's 'indeterminate system' (a RuntimeError) at the next update."""
    pg = slam.PoseGraph()
    pg.add_submap(np.eye(4))
    pg.add_submap(np.eye(4), 0.1)
    far = np.eye(4)
    far[1, 3] = 3e6
    with pytest.raises(ValueError, match="T_world_submap_nav"):
        pg.add_submap(far, 0.1)
    assert pg.num_submaps == 2
    assert np.all(np.isfinite(pg.update()))


@fuzz(40)
@given(
    prior_exponents=st.lists(st.floats(-6, 6), min_size=6, max_size=6),
    drift_exponents=st.lists(st.floats(-14, 8), min_size=6, max_size=6),
    duration_exponent=st.floats(-3, 4),
    step_exponent=st.floats(-2, 3),
)
def test_any_valid_noise_leaves_a_solvable_graph(prior_exponents, drift_exponents, duration_exponent, step_exponent):
    """Valid sigmas spanning many orders (a prior of 1e3 rad beside 1e-3 m, a yaw drift of
    radians over 700 m steps) left iSAM2's Cholesky an 'indeterminate system' (RuntimeError)
    in 252 of 300 random graphs and the graph unusable. Whatever the noise, the graph solves (on QR
    when Cholesky cannot) and, its odometry exact, holds the navigation's poses; the marginals
    are covariances (to round-off: a marginal of sigmas across 18 orders is that close to
    singular)."""
    from vogjax.config import NavNoise

    duration_s, step_m = 10.0**duration_exponent, 10.0**step_exponent
    names = ["sigma2_x", "sigma2_y", "sigma2_yaw", "sigma2_z", "sigma2_pitch", "sigma2_roll"]
    noise = NavNoise(**{n: 10.0**e / duration_s for n, e in zip(names, drift_exponents)})
    graph = slam.PoseGraph(noise, prior_sigmas=10.0 ** np.array(prior_exponents))
    nav = [exp_se3(np.array([0.0, 0.0, 0.3 * j, step_m * j, 0.4 * step_m * j, 0.0])) for j in range(5)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the switch to QR says so
        for T in nav:
            try:
                graph.add_submap(T, duration_s)
            except ValueError as error:  # a step of more than MAX_STEP_SIGMAS: refused as documented
                assert "T_world_submap_nav" in str(error)
                return
            graph.update()
    np.testing.assert_allclose(graph.poses(), np.stack(nav), atol=1e-6 * max(step_m, 1.0))
    for covariance in graph.marginals(np.arange(5)):
        values = np.linalg.eigvalsh((covariance + covariance.T) / 2)  # semi-definite, to round-off
        assert np.all(np.isfinite(covariance)) and values[0] >= -1e-12 * values[-1] and values[-1] > 0


def test_the_papers_graph_stays_on_cholesky():
    graph = slam.PoseGraph()
    for j in range(4):
        graph.add_submap(exp_se3(np.array([0.0, 0.0, 0.1 * j, 5.0 * j, 0.0, 0.0])), 600.0)
        graph.update()
    assert graph.factorization == "CHOLESKY"


@fuzz(25)
@given(
    seed=st.integers(0, 2**16),
    offset_m=st.sampled_from([0.0, 40.0, 3e3]),
    free=st.sampled_from(["translation", "yaw", "all"]),
    registration_sigma_m=st.sampled_from([0.0, 0.025]),
    floors=st.booleans(),
    noise_m=st.sampled_from([0.0, 0.003]),
    scene=st.sampled_from(["room", "floor", "wall"]),
)
def test_every_closure_the_detector_returns_enters_the_graph(
    seed, offset_m, free, registration_sigma_m, floors, noise_m, scene
):
    """A closure the detector accepts is one the pose graph can take: its covariance within
    the graph's bounds whatever the fit (exact, degenerate, far from the frame's origin) and
    the settings (a perfect fit without registration_sigma_m or floors was refused, and the
    run stopped)."""
    from vogjax.config import LoopClosureConfig

    rng = np.random.default_rng(seed)
    parts = [
        np.c_[rng.uniform(0, 6, 500), rng.uniform(0, 4, 500), np.zeros(500)],
        np.c_[np.zeros(500), rng.uniform(0, 4, 500), rng.uniform(0, 3, 500)],
        np.c_[rng.uniform(0, 6, 500), np.zeros(500), rng.uniform(0, 3, 500)],
    ]
    cloud = {"room": np.concatenate(parts), "floor": parts[0], "wall": parts[1]}[scene] + [offset_m, 0.0, 0.0]
    truth = exp_se3(np.r_[0.0, 0.0, rng.normal(0, 0.02), rng.normal(0, 0.05, 2), 0.0])
    seen = (cloud - truth[:3, 3]) @ truth[:3, :3] + rng.normal(0, noise_m, cloud.shape)
    clouds = [cloud, cloud[:10], seen]
    bounds = (cloud.min(axis=0) - 0.5, cloud.max(axis=0) + 0.5)
    poses = np.stack([np.eye(4), np.eye(4), truth])
    extra = {} if floors else {"min_sigma_rotation_rad": 0.0, "min_sigma_translation_m": 0.0}
    config = LoopClosureConfig(
        icp=IcpConfig(max_correspondence_m=0.3, free=free), registration_sigma_m=registration_sigma_m, **extra
    )
    accepted, _ = slam.LoopClosureDetector(config=config).detect(
        2, clouds, [bounds, None, bounds], poses, poses, np.array([0.0, 600.0, 1200.0])
    )
    graph = slam.PoseGraph(config=vj.config.PoseGraphConfig(screen="none"))
    for T in poses:
        graph.add_submap(T, 600.0)
    for closure in accepted:
        graph.add_loop_closure(closure.i, closure.k, closure.T_i_k, closure.covariance, closure.basis)
    assert np.all(np.isfinite(graph.update()))


@pytest.mark.parametrize("field", ["sigma2_x", "sigma2_yaw", "sigma2_z", "sigma2_roll"])
def test_a_drift_too_large_to_weigh_is_refused_naming_it(field):
    """1e308 m^2/s over 600 s overflowed to infinite variances: the graph solved, and its
    marginals were NaN."""
    from vogjax.config import NavNoise

    graph = slam.PoseGraph(NavNoise(**{field: 1e308}))
    graph.add_submap(np.eye(4))
    with pytest.raises(ValueError, match="NavNoise over duration_s"):
        graph.add_submap(np.eye(4), 600.0)
    graph.update()
    assert graph.num_submaps == 1 and np.all(np.isfinite(graph.marginals([0])))
