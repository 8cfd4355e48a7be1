"""Fuzzing the maps (issue 17): VoxelMap, VogMap, GlobalMap, ConfidenceMap and their configs.

Every call gets valid and hostile arguments (wrong shapes and dtypes, NaN and inf, huge and tiny
magnitudes, empty arrays, strings, None, far-away coordinates, non-rigid poses, unknown ids) and
must either return a correct result, checked against an independent reference where that is
cheap (tests/reference.py walks voxels one by one), or raise ValueError naming the argument and
leave the map as it was. Any other exception fails the test; so does a call that takes longer
than TIME_LIMIT_S or grows the process's peak memory by more than MEMORY_LIMIT_BYTES.

The default run stays fast (derandomized, a few dozen examples per entry point); set
VOGJAX_FUZZ_EXAMPLES=N to try N examples per entry point, freshly random each run.

The helpers here (settings, `attempt`, hostile-value strategies) are shared by the other
tests/test_fuzz_*.py files.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import os
import resource
import time

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.kernels import hashing
from vogjax.maps import blockmap

from . import reference as ref
from . import submap_helpers as helpers

# ------------------------------------------------------------------------------ settings

EXAMPLES = int(os.environ.get("VOGJAX_FUZZ_EXAMPLES", "0") or 0)
TIME_LIMIT_S = 20.0  # per call; the machine is shared, tiny inputs take milliseconds
MEMORY_LIMIT_BYTES = 1 << 30


def fuzz(examples: int):
    """Hypothesis settings of one fuzz test: `examples` by default (derandomized, so the suite
    is repeatable), VOGJAX_FUZZ_EXAMPLES when set (random)."""
    return settings(
        max_examples=EXAMPLES or examples,
        deadline=None,
        derandomize=not EXAMPLES,
        database=None,
        print_blob=True,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
            HealthCheck.function_scoped_fixture,
            HealthCheck.large_base_example,
        ],
    )


# ------------------------------------------------------------------------------ outcome checks

REFUSED = object()  # what `attempt` returns when the call raised a proper ValueError


def peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


@contextlib.contextmanager
def bounded(what: str, limit_s: float = TIME_LIMIT_S):
    """Fails when the block takes longer than `limit_s` (a hang, not a speed check) or raises the process's peak
    resident memory by more than MEMORY_LIMIT_BYTES."""
    peak, start = peak_rss_bytes(), time.perf_counter()
    yield
    seconds, grown = time.perf_counter() - start, peak_rss_bytes() - peak
    assert seconds < limit_s, f"{what} took {seconds:.1f} s"
    assert grown < MEMORY_LIMIT_BYTES, f"{what} grew the peak memory by {grown / 2**20:.0f} MiB"


def same(a, b) -> bool:
    """Deep equality of snapshots: arrays bit for bit (NaN equal to NaN), tuples/lists/dicts."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return isinstance(b, (tuple, list)) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc")
    return a == b


def attempt(call, names, snapshot=None, expect: str = "either", what: str = "call"):
    """Run `call()`. A ValueError must name one of `names` and leave `snapshot()` as it was
    (returns REFUSED); any other exception propagates (a finding). `expect`: "valid" (must not
    be refused), "invalid" (must be refused) or "either"."""
    before = snapshot() if snapshot else None
    with bounded(what):
        try:
            result = call()
        except ValueError as error:
            message = str(error)
            assert expect != "valid", f"{what}: valid input refused: {message}"
            assert any(name in message for name in names), f"{what}: {message!r} names none of {names}"
            if snapshot:
                assert same(before, snapshot()), f"{what}: state changed by a refused call ({message})"
            return REFUSED
    assert expect != "invalid", f"{what}: invalid input accepted"
    return result


# ------------------------------------------------------------------------------ hostile values

SPECIALS = [math.nan, math.inf, -math.inf]
HUGE = [1e300, -1e300, 7.2e7, 1e7, -1e7, 3e38, 1e200]
TINY = [1e-320, 1e-200, 5e-324, -1e-310]
RAGGED = [[1.0, 2.0], [3.0]]
JUNK = [
    None,
    "abc",
    ["a", "b", "c"],
    [["1", "2", "3"]],
    {"x": 1},
    b"\x00\x01",
    True,
    object(),
    RAGGED,
    (1, 2, 3, 4),
    "1,2,3",
]
# ragged index lists are left to test_ragged_ids_are_refused_naming_the_argument
JUNK_IDS = [j for j in JUNK if j is not RAGGED]


@st.composite
def generic_floats(draw, lo=-4.0, hi=4.0):
    """Finite values of either sign away from exact voxel boundaries (so references that break
    ties differently still agree)."""
    return draw(st.floats(lo, hi, allow_nan=False, allow_infinity=False)) + 0.0137 * draw(st.integers(1, 7))


@st.composite
def hostile_array(draw, shape: tuple, good, allow_empty: bool = True):
    """(value, expectation): a valid array drawn by `good` (a strategy of (shape) float64
    arrays), or one damaged in one of many ways. expectation: "valid", "invalid" or "either"."""
    kind = draw(st.sampled_from(["valid"] * 6 + ["special", "shape", "dtype", "junk", "empty", "list", "cast"]))
    value = draw(good)
    if kind == "valid":
        return value, "valid"
    if kind == "cast":  # other numeric dtypes of the same values: int and float32/float16 are fine
        dtype = draw(st.sampled_from([np.float32, np.int64, np.int32, np.float16, np.uint8, np.bool_, np.complex128]))
        if dtype in (np.float32, np.int64, np.int32):
            return value.astype(dtype), "valid" if dtype is not np.float32 or np.all(np.abs(value) < 3e38) else "either"
        return value.astype(dtype) if dtype is not np.float16 else value.astype(dtype), (
            "invalid" if dtype in (np.bool_, np.complex128) else "either"
        )
    if kind == "list":  # an empty list has no shape (N,3): either answer is fine
        return value.tolist(), "valid" if value.size else "either"
    if kind == "special" and value.size:
        flat = value.reshape(-1).copy()
        flat[draw(st.integers(0, flat.size - 1))] = draw(st.sampled_from(SPECIALS))
        return flat.reshape(value.shape), "invalid"
    if kind == "shape":
        wrong = draw(st.sampled_from([(4,), (2, 2), (3, 4), (1, 1, 3), (3, 3, 3), ()]))
        if wrong == tuple(s for s in shape):
            wrong = (5, 5)
        return np.ones(wrong), "either" if len(wrong) == len(shape) and all(
            s in (-1, w) for s, w in zip(shape, wrong)
        ) else "invalid"
    if kind == "dtype":
        return value.astype(draw(st.sampled_from([np.bool_, np.complex64, object, "U8"]))), "invalid"
    if kind == "empty" and allow_empty:
        return np.zeros((0,) + tuple(3 for s in shape[1:])), "valid" if shape[0] == -1 else "invalid"
    return draw(st.sampled_from(JUNK)), "invalid"


def points_array(n_lo=0, n_hi=12, lo=-4.0, hi=4.0):
    return (
        st.integers(n_lo, n_hi)
        .flatmap(lambda n: st.lists(st.tuples(*[generic_floats(lo, hi)] * 3), min_size=n, max_size=n))
        .map(lambda rows: np.array(rows, dtype=np.float64).reshape(-1, 3))
    )


def vector3(lo=-2.0, hi=2.0):
    return st.tuples(*[generic_floats(lo, hi)] * 3).map(lambda v: np.array(v))


# an offset for whole scans: near the origin, far away, or near the edge of the key range
OFFSETS = st.sampled_from([0.0, 0.0, 0.0, 1234.5, -98765.4, 1.5e5])

# ------------------------------------------------------------------------------ VoxelMap

CFG = vj.MapConfig(voxel_size=0.25, max_range=3.0)


def cells_of(vmap) -> dict:
    centres, values = vmap.voxels()
    keys = np.floor(centres / vmap.config.voxel_size).astype(np.int64)
    return {tuple(k): v for k, v in zip(keys.tolist(), values)}


def base_map(offset=0.0):
    """A small VoxelMap with three scans and its reference cells."""
    rng = np.random.default_rng(7)
    vmap, cells = vj.VoxelMap(CFG), {}
    for _ in range(3):
        origin = (rng.uniform(-0.5, 0.5, 3) + offset).astype(np.float32)
        points = (origin + rng.normal(size=(25, 3)) * 1.6).astype(np.float32)
        vmap.integrate_scan(origin, points)
        ref.insert_scan(cells, origin, points, CFG)
    return vmap, cells


@pytest.fixture(scope="module")
def warm():
    """Compile and load every kernel once, so examples measure the calls, not the compiler."""
    vmap, _ = base_map()
    vmap.integrate_scans(np.zeros((1, 3)), np.ones((1, 3)), [0])
    vmap.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1.0)
    vmap.line_query(np.zeros((1, 3)), np.ones((1, 3)))
    vmap.state(np.zeros((1, 3)))
    vog = helpers.random_vog(np.random.default_rng(0), 2, CFG)
    vog.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1.0)
    vog.state(np.zeros((1, 3)))
    vog.line_query(np.zeros((1, 3)), np.ones((1, 3)))
    g = vj.GlobalMap(CFG)
    g.merge(vog)
    g.update_poses(vog)
    g.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1.0)
    crm = vj.ConfidenceMap(CRM_CFG)
    crm.integrate_scan(np.zeros(3), np.ones((2, 3)))
    crm.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1.0)
    crm.distribution(np.zeros((1, 3)))
    return True


def in_key_range(array, voxel_size) -> bool:
    return np.abs(array).max(initial=0.0) / voxel_size < hashing.VOXEL_KEY_LIMIT - 2


@fuzz(60)
@given(data=st.data())
def test_voxelmap_integrate_scan(warm, data):
    """One scan, valid or hostile: the map equals OctoMap's rule applied by the reference."""
    offset = data.draw(OFFSETS)
    vmap, cells = base_map(offset)
    origin_good = vector3().map(lambda v: v + offset)
    points_good = points_array().map(lambda p: p + offset)
    origin, origin_expect = data.draw(hostile_array((3,), origin_good, allow_empty=False))
    points, points_expect = data.draw(hostile_array((-1, 3), points_good))
    if data.draw(st.booleans()) and points_expect == "valid" and np.size(points):
        # beams far beyond max_range, up to the edge of the key range
        scale = data.draw(st.sampled_from([10.0, 1e3, 1e5, 5e5, 3e6]))
        points = np.asarray(points, np.float64) * scale
        points_expect = "valid" if in_key_range(points, CFG.voxel_size) else "invalid"
    expect = (
        "invalid"
        if "invalid" in (origin_expect, points_expect)
        else "valid"
        if origin_expect == points_expect == "valid"
        else "either"
    )
    result = attempt(
        lambda: vmap.integrate_scan(origin, points),
        ["origin", "points"],
        vmap.voxels,
        expect,
        "VoxelMap.integrate_scan",
    )
    if result is REFUSED:
        return
    o = np.asarray(origin, np.float64).astype(np.float32)
    p = np.asarray(points, np.float64).astype(np.float32).reshape(-1, 3)
    ref.insert_scan(cells, o, p, CFG)
    assert cells_of(vmap) == cells


@fuzz(40)
@given(data=st.data())
def test_voxelmap_integrate_scans(warm, data):
    """A batch, valid or hostile: the same map, bit for bit, as integrate_scan scan by scan."""
    vmap, _ = base_map()
    twin, _ = base_map()
    scans = data.draw(st.integers(0, 4))
    origins_good = points_array(scans, scans, -1.0, 1.0)
    origins, origins_expect = data.draw(hostile_array((-1, 3), origins_good))
    count = np.shape(origins)[0] if origins_expect == "valid" else 3
    points, points_expect = data.draw(hostile_array((-1, 3), points_array()))
    n = np.shape(points)[0] if points_expect == "valid" else 1
    index_kind = data.draw(
        st.sampled_from(
            ["valid", "valid", "valid", "float", "negative", "beyond", "length", "junk", "bool", "unsorted"]
        )
    )
    scan_index = np.array(data.draw(st.lists(st.integers(0, max(count - 1, 0)), min_size=n, max_size=n)), np.int64)
    index_expect = "valid" if count > 0 or n == 0 else "invalid"
    if index_kind == "float":  # an empty one is what [] reads as: nothing to index, accepted
        scan_index, index_expect = scan_index.astype(np.float64), "invalid" if n else index_expect
    elif index_kind == "negative" and n:
        scan_index[0], index_expect = -1, "invalid"
    elif index_kind == "beyond" and n:
        scan_index[-1], index_expect = count, "invalid"
    elif index_kind == "length":
        scan_index, index_expect = np.zeros(n + 1, np.int64), "invalid"
    elif index_kind == "junk":
        scan_index, index_expect = data.draw(st.sampled_from(JUNK_IDS)), "invalid"
    elif index_kind == "bool":
        scan_index, index_expect = scan_index.astype(bool), "invalid"
    elif index_kind == "unsorted":
        scan_index = scan_index[::-1].copy()
    expects = (origins_expect, points_expect, index_expect)
    expect = "invalid" if "invalid" in expects else "valid" if set(expects) == {"valid"} else "either"
    result = attempt(
        lambda: vmap.integrate_scans(origins, points, scan_index),
        ["origins", "points", "scan_index"],
        vmap.voxels,
        expect,
        "VoxelMap.integrate_scans",
    )
    if result is REFUSED:
        return
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    s = np.asarray(scan_index).reshape(-1)
    for k in range(o.shape[0]):
        twin.integrate_scan(o[k], p[s == k])
    assert same(vmap.voxels(), twin.voxels())


@fuzz(40)
@given(data=st.data())
def test_voxelmap_point_queries(warm, data):
    """log_odds, probability and state: the reference's cell values, 0 / 0.5 / UNKNOWN where unknown."""
    vmap, cells = base_map()
    points, expect = data.draw(hostile_array((-1, 3), points_array(0, 20, -5.0, 5.0)))
    if expect == "valid" and data.draw(st.booleans()):
        points = np.asarray(points, np.float64) * data.draw(st.sampled_from([1e4, 1e5, 1e7]))
        expect = "valid" if in_key_range(points, CFG.voxel_size) else "either"
    for name in ("log_odds", "probability", "state"):
        result = attempt(lambda: getattr(vmap, name)(points), ["points"], vmap.voxels, expect, f"VoxelMap.{name}")
        if result is REFUSED:
            continue
        queries = np.asarray(points, np.float64).astype(np.float32).reshape(-1, 3)
        stored = [cells.get(ref.key_of(q, CFG.voxel_size)) for q in queries]
        values = np.array([0.0 if v is None else v for v in stored], np.float32)
        assert result.shape == (len(queries),)
        if name == "log_odds":
            assert result.dtype == np.float32 and np.array_equal(result, values)
        elif name == "probability":
            assert result.dtype == np.float32
            np.testing.assert_allclose(result, 1 - 1 / (1 + np.exp(values.astype(np.float64))), rtol=1e-6)
        else:
            assert result.dtype == np.int8
            assert result.tolist() == [ref.state_of(v, CFG) for v in stored]


def ray_reference(cells, origin, direction, max_range, cfg, box):
    """Reference ray cast; rays longer than the walk to the map's box are walked only that far
    (nothing lies beyond it): returns (hit, distance, num_free, unknown_at_least, exact)."""
    lo, hi = box
    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(d != 0, (lo - origin) / d, -np.inf)
        t2 = np.where(d != 0, (hi - origin) / d, -np.inf)
        inside = (origin >= lo) & (origin <= hi)
        t_far = np.min(np.where(d != 0, np.maximum(t1, t2), np.where(inside, np.inf, -np.inf)))
    reach = max(float(t_far), 0.0) + 2 * cfg.voxel_size
    walk = min(max_range, reach)
    hit, distance, unknown, free = ref.raycast(cells, origin, d, walk, cfg)
    exact = walk == max_range
    if not hit and not exact:
        distance = max_range
    return hit, distance, free, unknown, exact


def map_box(cells, cfg):
    keys = np.array(list(cells))
    return keys.min(axis=0) * cfg.voxel_size, (keys.max(axis=0) + 1) * cfg.voxel_size


RANGES = st.one_of(st.floats(0.01, 12.0), st.sampled_from([7.2e7, 1e300, 1e12, 4096 * 0.25, 5e-324, 1e-300]))


@st.composite
def ray_arguments(draw, count_hi=6):
    """(origins, directions, max_range, expectation)."""
    count = draw(st.integers(0, count_hi))
    origins_good = points_array(count, count, -2.0, 2.0)
    directions_good = points_array(count, count, -1.0, 1.0)
    origins, e1 = draw(hostile_array((-1, 3), origins_good))
    directions, e2 = draw(hostile_array((-1, 3), directions_good))
    if e2 == "valid" and draw(st.booleans()):  # huge and tiny directions
        directions = np.asarray(directions, np.float64) * draw(st.sampled_from([1e200, 1e-200, 1e-320, 1e300]))
        e2 = "either" if not np.all(np.isfinite(directions)) or np.any(np.all(directions == 0, axis=1)) else "valid"
    if e1 == "valid" and draw(st.integers(0, 3)) == 0:  # far from the map
        origins = np.asarray(origins, np.float64) + draw(st.sampled_from([[1e5, 0, 0], [0, -2e6, 0], [0, 0, 3e6]]))
        e1 = "valid" if in_key_range(origins, CFG.voxel_size) else "invalid"
    if e1 == e2 == "valid" and np.shape(origins) != np.shape(directions):
        e2 = "invalid"
    if e2 == "valid" and np.any(np.all(np.asarray(directions, np.float64).reshape(-1, 3) == 0, axis=1)):
        e2 = "invalid"  # a cast to integers can zero a direction
    kind = draw(st.sampled_from(["scalar"] * 4 + ["array", "junk", "bad"]))
    n = np.shape(origins)[0] if e1 == "valid" else count
    if kind == "scalar":
        max_range, e3 = draw(RANGES), "valid"
        if draw(st.integers(0, 5)) == 0:
            max_range, e3 = draw(st.sampled_from([0.0, -1.0, math.inf, math.nan, -math.inf])), "invalid"
    elif kind == "array":
        max_range = np.array(draw(st.lists(RANGES, min_size=n, max_size=n)))
        e3 = "valid"
    elif kind == "bad":
        max_range, e3 = (
            draw(
                st.sampled_from(
                    [np.ones(n + 1), np.full(max(n, 1), -1.0), np.full(max(n, 1), math.nan), np.ones((max(n, 1), 1))]
                )
            ),
            "invalid",
        )
        if n == 0 and max_range.shape == (1,):
            e3 = "invalid"
    else:
        max_range, e3 = draw(st.sampled_from([j for j in JUNK if not isinstance(j, tuple)])), "invalid"
    if isinstance(max_range, np.ndarray) and max_range.dtype.kind == "f" and max_range.size and np.any(max_range == 0):
        e3 = "invalid"  # 5e-324 stays positive; zero does not arise from RANGES
    expects = (e1, e2, e3)
    expect = "invalid" if "invalid" in expects else "valid" if set(expects) == {"valid"} else "either"
    return origins, directions, max_range, expect


def check_rays(result, cells, origins, directions, max_range, cfg):
    """Well-formed results, equal to the reference walk where it is cheap."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    n = o.shape[0]
    ranges = np.broadcast_to(np.asarray(max_range, np.float64), (n,))
    assert result.hit.shape == result.distance.shape == result.num_unknown.shape == result.num_free.shape == (n,)
    assert result.hit.dtype == np.bool_ and result.distance.dtype == np.float32
    assert result.num_unknown.dtype == result.num_free.dtype == np.int32
    assert np.all(result.num_unknown >= 0) and np.all(result.num_free >= 0)
    assert np.all(result.distance >= 0) and np.all(result.distance <= ranges.astype(np.float32))
    box = map_box(cells, cfg)
    for k in range(n):
        if np.abs(o[k]).max() > 50:  # a far origin: too long for the Python walk; nothing to hit
            # unless the ray points at the map
            continue
        scaled = d[k] / np.abs(d[k]).max()
        hit, distance, free, unknown, exact = ray_reference(cells, o[k], scaled, float(ranges[k]), cfg, box)
        assert bool(result.hit[k]) == hit, f"ray {k}: hit {result.hit[k]}, reference {hit}"
        np.testing.assert_allclose(result.distance[k], np.float32(distance), rtol=1e-6, atol=1e-5)
        assert result.num_free[k] == free
        if exact:
            assert result.num_unknown[k] == unknown
        else:
            assert result.num_unknown[k] >= unknown


@fuzz(50)
@given(args=ray_arguments())
def test_voxelmap_raycast(warm, args):
    vmap, cells = base_map()
    origins, directions, max_range, expect = args
    result = attempt(
        lambda: vmap.raycast(origins, directions, max_range),
        ["origins", "directions", "max_range"],
        vmap.voxels,
        expect,
        "VoxelMap.raycast",
    )
    if result is not REFUSED:
        check_rays(result, cells, origins, directions, max_range, CFG)


def plain_rays(value) -> np.ndarray | None:
    """`value` as a float64 (R, 3) array, or None when it is no plain real (R, 3) array (junk,
    ragged, bool or complex: what the NumPy path's own checks refuse)."""
    try:
        array = np.asarray(value)
    except Exception:
        return None
    if array.dtype.kind not in "fiu" or array.dtype == np.bool_ or array.ndim != 2 or array.shape[1] != 3:
        return None
    return np.ascontiguousarray(array, np.float64)


@fuzz(50)
@given(args=ray_arguments())
def test_voxelmap_raycast_on_the_device_agrees_with_numpy(warm, args):
    """The same rays as Warp arrays: refused exactly when the NumPy path refuses them (NaN,
    infinities, zero directions, the key range, ranges), and bit for bit its answers."""
    vmap, _ = base_map()
    origins, directions, max_range, _ = args
    o, d = plain_rays(origins), plain_rays(directions)
    assume(o is not None and d is not None and o.shape == d.shape)
    count = o.shape[0]
    d_origins = wp.array(o, dtype=wp.float64, device=vmap.device)
    d_directions = wp.array(d, dtype=wp.float64, device=vmap.device)
    if (
        np.isscalar(max_range)
        and isinstance(max_range, (int, float, np.integer, np.floating))
        and not isinstance(max_range, bool)
    ):
        d_range = max_range
    elif (
        isinstance(max_range, np.ndarray)
        and max_range.dtype.kind in "fiu"
        and max_range.dtype != np.bool_
        and max_range.shape == (count,)
    ):
        d_range = wp.array(max_range.astype(np.float64), dtype=wp.float64, device=vmap.device)
    else:
        d_range = None
    assume(d_range is not None)
    host = attempt(
        lambda: vmap.raycast(origins, directions, max_range),
        ["origins", "directions", "max_range"],
        vmap.voxels,
        "either",
        "VoxelMap.raycast",
    )
    event("refused" if host is REFUSED else "answered")
    device = attempt(
        lambda: vmap.raycast(d_origins, d_directions, d_range),
        ["origins", "directions", "max_range"],
        vmap.voxels,
        "invalid" if host is REFUSED else "valid",
        "VoxelMap.raycast on the device",
    )
    if host is not REFUSED:
        for name in ("hit", "distance", "num_unknown", "num_free"):
            assert np.array_equal(getattr(device, name).numpy(), getattr(host, name)), name


@st.composite
def line_arguments(draw):
    count = draw(st.integers(0, 5))
    starts, e1 = draw(hostile_array((-1, 3), points_array(count, count, -4.0, 4.0)))
    ends, e2 = draw(hostile_array((-1, 3), points_array(count, count, -4.0, 4.0)))
    if e2 == "valid" and draw(st.integers(0, 3)) == 0 and np.size(ends):
        ends = np.asarray(ends, np.float64) * draw(st.sampled_from([1e3, 1e4, 1e5, 1e8]))
        long = (
            np.abs(
                np.floor(ends / CFG.voxel_size)
                - np.floor(np.asarray(starts, np.float64).reshape(-1, 3)[: len(ends)] / CFG.voxel_size)
            )
            .sum(axis=1)
            .max(initial=0)
            + 1
            > blockmap.MAX_LINE_VOXELS
            if e1 == "valid" and np.shape(starts) == np.shape(ends)
            else None
        )
        e2 = "invalid" if long or not in_key_range(ends, CFG.voxel_size) else "either" if long is None else "valid"
    if e1 == e2 == "valid" and np.shape(starts) != np.shape(ends):
        e2 = "invalid"
    expects = (e1, e2)
    expect = "invalid" if "invalid" in expects else "valid" if set(expects) == {"valid"} else "either"
    return starts, ends, expect


@fuzz(40)
@given(args=line_arguments())
def test_voxelmap_line_query(warm, args):
    vmap, cells = base_map()
    starts, ends, expect = args
    result = attempt(
        lambda: vmap.line_query(starts, ends), ["starts", "ends"], vmap.voxels, expect, "VoxelMap.line_query"
    )
    if result is REFUSED:
        return
    values, lengths = result
    s = np.asarray(starts, np.float64).astype(np.float32).reshape(-1, 3)
    e = np.asarray(ends, np.float64).astype(np.float32).reshape(-1, 3)
    assert values.dtype == np.float32 and lengths.dtype == np.int32 and lengths.shape == (len(s),)
    assert values.shape == (len(s), int(lengths.max(initial=0)))
    for k in range(len(s)):
        assert np.all(np.isnan(values[k, lengths[k] :]))
        if lengths[k] <= 2000:
            expected = ref.line_values(cells, s[k], e[k], CFG)
            assert lengths[k] == len(expected)
            assert np.array_equal(values[k, : lengths[k]], np.float32(expected))


# ------------------------------------------------------------------------------ MapConfig

MAP_FIELDS = {
    "voxel_size": st.sampled_from([0.1, 0.25, 1e-4, 9e-5, 0.0, -0.1, 1e300, 5e-324, 1000.0, 1000.5]),
    "prob_hit": st.sampled_from([0.75, 0.5, 0.51, 1.0, 0.0, 0.99999, 1.5]),
    "prob_miss": st.sampled_from([0.2, 0.5, 0.49, 0.0, 1e-300, -0.1]),
    "occupied_threshold": st.sampled_from([0.7, 0.3, 1.0, 0.0, 0.5]),
    "free_threshold": st.sampled_from([0.3, 0.7, 0.0, 0.2, 0.5]),
    "clamp_min": st.sampled_from([0.1192, 0.0, 0.97, 1.0, -0.1]),
    "clamp_max": st.sampled_from([0.971, 1.0, 0.1, 0.0, 1.1]),
    "max_range": st.sampled_from([11.0, 409.6, 409.7, 1e300, 7.2e7, 0.0, -1.0, 5e-324, 1e-3]),
}
BAD_VALUES = st.sampled_from([math.nan, math.inf, -math.inf, None, "0.1", [0.1], True, 1j, object()])


def map_rules_hold(f: dict) -> bool:
    """MapConfig's documented rules, written out independently."""

    def p(x):
        return 0 < x < 1

    return (
        1e-4 <= f["voxel_size"] <= 1000
        and p(f["prob_hit"])
        and p(f["prob_miss"])
        and p(f["occupied_threshold"])
        and p(f["free_threshold"])
        and 0 <= f["clamp_min"] < 1
        and 0 < f["clamp_max"] <= 1
        and f["max_range"] > 0
        and f["prob_miss"] < 0.5 < f["prob_hit"]
        and f["free_threshold"] <= f["occupied_threshold"]
        and f["clamp_min"] < f["clamp_max"]
        and f["max_range"] <= MAX_RANGE_VOXELS * f["voxel_size"]
    )


@fuzz(150)
@given(data=st.data())
def test_map_config(data):
    """Every field in and out of range or of the wrong type: a config exactly when the rules
    hold, else a ValueError naming a field; from_dict refuses unknown keys and wrong types."""
    chosen = {name: data.draw(strategy) for name, strategy in MAP_FIELDS.items() if data.draw(st.integers(0, 2)) > 0}
    junk = data.draw(st.one_of(st.none(), st.sampled_from(list(MAP_FIELDS))))
    fields = dict(chosen)
    if junk is not None:
        fields[junk] = data.draw(BAD_VALUES)
    full = {f: getattr(vj.MapConfig, f) for f in MAP_FIELDS} | fields
    valid = junk is None and map_rules_hold(full)
    names = [f"MapConfig.{f}" for f in MAP_FIELDS]
    config = attempt(lambda: vj.MapConfig(**fields), names, expect="valid" if valid else "invalid", what="MapConfig")
    if config is not REFUSED:
        assert all(getattr(config, f) == v for f, v in full.items())
    extra = data.draw(st.sampled_from([{}, {"voxel_sise": 0.1}, {"max_range": "11"}, {"voxel_size": 1}]))
    document = {**fields, **extra}
    valid_document = (
        valid
        and "voxel_sise" not in extra
        and "max_range" not in extra
        and (extra.get("voxel_size") is None or map_rules_hold(full | {"voxel_size": 1.0}))
    )
    loaded = attempt(
        lambda: vj.MapConfig.from_dict(document),
        names + ["voxel_sise", "MapConfig"],
        expect="valid" if valid_document else "either",
        what="MapConfig.from_dict",
    )
    if loaded is not REFUSED:
        assert valid or all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in document.values())
        assert all(getattr(loaded, f) == v for f, v in document.items())


# ------------------------------------------------------------------------------ VogMap


def rotation(yaw, pitch, roll):
    return vj.geometry.rotation_from_ypr(yaw, pitch, roll)


@st.composite
def poses(draw, count=None, spread=2.0):
    """(value, expectation): rigid poses (n,4,4) (or one (4,4) when count is None), or hostile ones."""
    n = 1 if count is None else count
    angles = draw(st.lists(st.tuples(*[st.floats(-math.pi, math.pi)] * 3), min_size=n, max_size=n))
    shifts = draw(st.lists(st.tuples(*[st.floats(-spread, spread)] * 3), min_size=n, max_size=n))
    good = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        good[k, :3, :3] = rotation(*angles[k])
        good[k, :3, 3] = shifts[k]
    value = good[0] if count is None else good
    kind = draw(
        st.sampled_from(["valid"] * 5 + ["near", "scaled", "reflect", "row", "special", "shape", "junk", "far", "skew"])
    )
    if kind == "valid":
        return value, "valid"
    bad = np.array(value, dtype=np.float64)
    flat = bad.reshape(-1, 4, 4)
    if n == 0:
        return draw(st.sampled_from([np.zeros((1, 4, 4)), np.eye(3), "pose", None])), "invalid"
    if kind == "near":  # within the 1e-6 tolerance: accepted
        flat[0, 0, 0] += draw(st.sampled_from([1e-9, -5e-8, 1e-7]))
        return bad, "valid"
    if kind == "scaled":
        flat[0, :3, :3] *= draw(st.sampled_from([1.001, 2.0, 0.0, 1e300, 1 + 1e-4]))
        return bad, "invalid"
    if kind == "reflect":
        flat[0, :3, 0] *= -1
        return bad, "invalid"
    if kind == "row":
        flat[0, 3] = draw(st.sampled_from([[0, 0, 0, 2], [1, 0, 0, 1], [0, 0, 0, 1 + 1e-12]]))
        return bad, "invalid"
    if kind == "special":
        flat[0, draw(st.integers(0, 3)), draw(st.integers(0, 3))] = draw(st.sampled_from(SPECIALS))
        return bad, "invalid"
    if kind == "shape":
        # (an empty stack where one pose is due: see test_an_empty_pose_stack_is_not_a_pose)
        return draw(
            st.sampled_from(
                [np.eye(3), np.eye(4)[None, None], np.ones((n + 1, 4, 4)), np.eye(4).ravel()]
                + ([np.zeros((0, 4, 4))] if count is not None else [])
            )
        ), "invalid"
    if kind == "far":  # a valid rotation far away (the submaps' voxels then leave the key range)
        flat[0, :3, 3] = draw(st.sampled_from([[1e5, 0, 0], [0, 3e6, 0], [1e300, 0, 0]]))
        return bad, "either"
    if kind == "skew":
        flat[0, 0, 1] += 1e-3
        return bad, "invalid"
    return draw(st.sampled_from(JUNK)), "invalid"


def random_vog(n=2, cfg=CFG, seed=3):
    return helpers.random_vog(np.random.default_rng(seed), n, cfg, scans=2, beams=30, spread=2.0)


IDS = st.one_of(
    st.integers(-2, 4),
    st.lists(st.integers(-1, 4), max_size=3),
    st.sampled_from(
        [
            [],
            np.array([0, 1]),
            np.array([0.0]),
            [True],
            "0",
            None,
            [[0]],
            1.5,
            np.int64(1),
            [0, 0],
            np.uint8(1),
            2**63,
            -(2**63),
        ]
    ),
)


def ids_valid(ids, n) -> str:
    """ "valid", "invalid" or "either" for submap ids of a map of n submaps."""
    if isinstance(ids, bool) or ids is None or isinstance(ids, str):
        return "invalid"
    try:
        array = np.atleast_1d(np.asarray(ids))
    except (ValueError, OverflowError):
        return "invalid"
    if array.ndim != 1 or (array.size and array.dtype.kind not in "iu"):
        return "invalid"
    return "valid" if array.size == 0 or (array.min() >= 0 and array.max() < n) else "invalid"


@fuzz(60)
@given(data=st.data())
def test_vogmap_poses(warm, data):
    """add_submap, set_poses, pose, poses, submap, view with valid and hostile arguments, against a
    model list of poses; a refused call changes nothing."""
    vog = random_vog()
    model = [vog.pose(i) for i in range(vog.num_submaps)]
    for _ in range(data.draw(st.integers(1, 6))):
        op = data.draw(st.sampled_from(["add", "set", "pose", "poses", "submap", "view"]))
        snapshot = lambda: (vog.num_submaps, vog.poses())
        if op == "add":
            pose, expect = data.draw(poses())
            i = attempt(lambda: vog.add_submap(pose), ["pose"], snapshot, expect, "VogMap.add_submap")
            if i is not REFUSED:
                assert i == len(model)
                model.append(np.asarray(pose, np.float64).reshape(4, 4))
        elif op == "set":
            ids = data.draw(IDS)
            e1 = ids_valid(ids, len(model))
            n = np.atleast_1d(np.asarray(ids)).size if e1 == "valid" else 1
            new, e2 = data.draw(poses(count=n))
            expect = "invalid" if "invalid" in (e1, e2) else "valid" if e1 == e2 == "valid" else "either"
            if e1 == "valid" and len(set(np.atleast_1d(ids).tolist())) != n:
                expect = "either"  # repeated ids: which pose wins is not specified
            result = attempt(lambda: vog.set_poses(ids, new), ["ids", "poses"], snapshot, expect, "VogMap.set_poses")
            if result is not REFUSED:
                for k, i in enumerate(np.atleast_1d(np.asarray(ids)).tolist()):
                    model[i] = np.asarray(new, np.float64)[k]
        else:
            ids = data.draw(IDS)
            expect = ids_valid(ids, len(model))
            if op in ("pose", "submap"):
                if np.ndim(ids) != 0 or expect != "valid" or isinstance(ids, list):
                    expect = "either" if expect == "valid" else expect
                call = {"pose": vog.pose, "submap": vog.submap}[op]
                result = attempt(lambda: call(ids), ["i"], snapshot, expect, f"VogMap.{op}")
                if result is not REFUSED and op == "pose":
                    assert np.array_equal(result, model[int(np.asarray(ids).reshape(-1)[0])])
            elif op == "poses":
                expect = "valid" if ids is None else expect  # None: all of them
                result = attempt(lambda: vog.poses(ids), ["ids"], snapshot, expect, "VogMap.poses")
                if result is not REFUSED:
                    picked = np.arange(len(model)) if ids is None else np.atleast_1d(np.asarray(ids)).astype(int)
                    assert np.array_equal(result, np.array(model).reshape(-1, 4, 4)[picked].reshape(-1, 4, 4))
            else:
                expect = "valid" if ids is None else expect
                if (
                    expect == "valid"
                    and ids is not None
                    and len(set(np.atleast_1d(ids).tolist())) != np.atleast_1d(ids).size
                ):
                    expect = "invalid"  # one submap twice would count twice in every sum
                result = attempt(lambda: vog.view(ids), ["ids"], snapshot, expect, "VogMap.view")
                if result is not REFUSED:
                    picked = np.arange(len(model)) if ids is None else np.atleast_1d(np.asarray(ids)).astype(int)
                    assert result.num_submaps == len(picked)
                    assert np.array_equal(result.poses(), np.array(model).reshape(-1, 4, 4)[picked].reshape(-1, 4, 4))
        assert vog.num_submaps == len(model)
        assert np.array_equal(vog.poses(), np.array(model).reshape(-1, 4, 4))


@fuzz(40)
@given(data=st.data())
def test_vogmap_queries(warm, data):
    """Virtual queries: point values equal the brute-force sum over submaps; ray casts and line
    queries equal those of the full merge (the global map answers the same at voxel centres)."""
    vog = random_vog(seed=data.draw(st.integers(0, 3)))
    merged = vj.GlobalMap(CFG)
    merged.merge(vog)
    snapshot = lambda: (vog.poses(), [vog.submap(i).voxels() for i in range(vog.num_submaps)])
    op = data.draw(st.sampled_from(["points", "rays", "lines"]))
    if op == "points":
        points, expect = data.draw(hostile_array((-1, 3), points_array(0, 15, -4.0, 4.0)))
        result = attempt(lambda: vog.log_odds(points), ["points"], snapshot, expect, "VogMap.log_odds")
        if result is not REFUSED:
            p = np.asarray(points, np.float64).reshape(-1, 3)
            expected = np.nan_to_num(helpers.reference_values(vog, p), nan=0.0)
            assert result.dtype == np.float32 and np.array_equal(result, expected)
            assert np.array_equal(vog.state(p), blockmap.classify(helpers.reference_values(vog, p), CFG))
    elif op == "rays":
        origins, directions, max_range, expect = data.draw(ray_arguments(4))
        result = attempt(
            lambda: vog.raycast(origins, directions, max_range),
            ["origins", "directions", "max_range"],
            snapshot,
            expect,
            "VogMap.raycast",
        )
        if result is not REFUSED:
            expected = merged.raycast(origins, directions, max_range)
            for name in ("hit", "distance", "num_unknown", "num_free"):
                assert np.array_equal(getattr(result, name), getattr(expected, name)), name
    else:
        starts, ends, expect = data.draw(line_arguments())
        result = attempt(
            lambda: vog.line_query(starts, ends), ["starts", "ends"], snapshot, expect, "VogMap.line_query"
        )
        if result is not REFUSED:
            values, lengths = result
            expected_values, expected_lengths = merged.line_query(starts, ends)
            assert np.array_equal(lengths, expected_lengths)
            assert np.array_equal(values, expected_values, equal_nan=True)


# ------------------------------------------------------------------------------ GlobalMap


def global_state(g):
    return g.sums(), g.applied_ids, [g.applied_pose(i) for i in g.applied_ids]


def reference_sums(cfg, owners: dict, applied_poses: dict):
    """The reference: the sum, key by key, of one-submap merges, each submap (from the VogMap
    that added it) at the pose it was applied at. Sums and counts are additive over submaps."""
    total = {}
    for i, vog in owners.items():
        single = vj.GlobalMap(cfg)
        single.merge(vog.view([i], applied_poses[i][None]))
        for key, value, count in zip(*(a.tolist() for a in single.sums())):
            old = total.get(tuple(key), (0, 0))
            total[tuple(key)] = (old[0] + value, old[1] + count)
    return total


def sums_dict(g) -> dict:
    keys, sums, counts = g.sums()
    return {tuple(k): (s, c) for k, s, c in zip(keys.tolist(), sums.tolist(), counts.tolist())}


def marginals_case(draw, n):
    kind = draw(
        st.sampled_from(
            ["none", "none", "valid", "valid", "nan_row", "asym", "negative", "shape", "junk", "inf", "huge", "zeros"]
        )
    )
    rng = np.random.default_rng(draw(st.integers(0, 100)))
    a = rng.normal(size=(n, 6, 6)) * draw(st.sampled_from([1e-3, 1.0, 10.0]))
    good = a @ a.transpose(0, 2, 1)
    if kind == "none":
        return None, "valid"
    if kind == "valid":
        return good, "valid"
    if kind == "nan_row" and n:
        good[0] = np.nan
        return good, "valid"
    if kind == "zeros":
        return np.zeros((n, 6, 6)), "valid"
    if kind == "huge":
        return good * 1e300, "either"
    if kind == "asym" and n:
        good[0, 0, 1] += 1.0
        return good, "invalid"
    if kind == "negative" and n:
        good[0] = -np.eye(6)
        return good, "invalid"
    if kind == "inf" and n:
        good[0, 2, 2] = np.inf
        return good, "invalid"
    if kind == "shape":
        return np.zeros((n + 1, 6, 6)), "invalid"
    # (complex marginals: see test_complex_and_text_arrays_are_refused)
    return draw(st.sampled_from(["marginals", [1, 2], [["a"] * 6] * 6, None if False else {"m": 1}])), "invalid"


EPS = st.one_of(
    st.sampled_from([0.0, 1e-2, 2e-3, 1e300, -1.0, math.nan, math.inf, "auto", "big", None, True, [0.1]]),
    st.floats(0, 1),
)
EPS_DEFAULTS = {"eps_rot": 1e-2, "eps_trans": 2e-3, "eps_cov": "auto", "eps_move_m": 0.0}


def eps_valid(name, value) -> str:
    if isinstance(value, bool) or value is None or isinstance(value, list):
        return "invalid"
    if isinstance(value, str):
        return "valid" if name == "eps_cov" and value == "auto" else "invalid"
    return "valid" if math.isfinite(value) and value >= 0 else "invalid"


def combined(*expects) -> str:
    return "invalid" if "invalid" in expects else "valid" if set(expects) <= {"valid"} else "either"


@fuzz(40)
@given(data=st.data())
def test_globalmap_sequences(warm, data):
    """merge / add / update_poses / set_poses / integrate with valid and hostile arguments
    (marginals, thresholds, ids, other maps): after every call the global map equals the sum of
    its submaps merged one by one at the poses they were applied at; a refused call changes
    nothing; a submap changed after it was added is never undone with its new contents."""
    vog = random_vog(3, seed=data.draw(st.integers(0, 3)))
    other = random_vog(3, seed=11)  # another VogMap of the same config
    g = vj.GlobalMap(CFG)
    owners, applied = {}, {}  # the model: which VogMap added each submap, at which pose
    thresholds = [k for k in EPS_DEFAULTS if k in inspect.signature(g.update_poses).parameters]
    for _ in range(data.draw(st.integers(1, 5))):
        op = data.draw(st.sampled_from(["merge", "add", "update", "update", "move", "integrate"]))
        target = data.draw(st.sampled_from(["vog"] * 5 + ["other", "none", "voxelmap", "config"]))
        m = {
            "vog": vog,
            "other": other,
            "none": None,
            "voxelmap": vj.VoxelMap(CFG),
            "config": vj.VogMap(vj.MapConfig(voxel_size=0.5)),
        }[target]
        is_vogmap = target in ("vog", "other")
        foreign = [i for i, owner in owners.items() if owner is not m]  # applied from another VogMap
        snapshot = lambda: global_state(g)
        marginals, m_expect = marginals_case(data.draw, 3)
        if op == "merge":
            expect = combined("valid" if is_vogmap else "invalid", m_expect)
            if (
                attempt(lambda: g.merge(m, marginals), ["vog", "marginals"], snapshot, expect, "GlobalMap.merge")
                is not REFUSED
            ):
                owners, applied = {i: m for i in range(3)}, {i: m.pose(i) for i in range(3)}
        elif op == "add":
            ids = data.draw(IDS)
            id_expect = ids_valid(ids, 3)
            listed = np.atleast_1d(np.asarray(ids)).tolist() if id_expect == "valid" else []
            if len(set(listed)) != len(listed) or set(listed) & set(owners):
                id_expect = "invalid"
            # adding another VogMap's submaps beside those already there: not specified
            target_expect = ("valid" if not foreign else "either") if is_vogmap else "invalid"
            expect = combined(target_expect, m_expect, id_expect)
            if (
                attempt(
                    lambda: g.add(m, ids, marginals), ["vog", "marginals", "ids"], snapshot, expect, "GlobalMap.add"
                )
                is not REFUSED
            ):
                owners.update({i: m for i in listed})
                applied.update({i: m.pose(i) for i in listed})
        elif op == "update":
            eps = {
                name: data.draw(EPS) if data.draw(st.integers(0, 3)) == 0 else EPS_DEFAULTS[name] for name in thresholds
            }
            target_expect = ("invalid" if foreign else "valid") if is_vogmap else "invalid"
            expect = combined(target_expect, m_expect, *[eps_valid(k, v) for k, v in eps.items()])
            report = attempt(
                lambda: g.update_poses(m, marginals, **eps),
                ["vog", "marginals", *thresholds],
                snapshot,
                expect,
                "GlobalMap.update_poses",
            )
            if report is not REFUSED:
                for i in report.reapplied:
                    applied[i] = m.pose(i)
                assert set(report.reapplied) <= set(report.moved) <= set(owners)
        elif op == "move":
            ids = data.draw(st.lists(st.integers(0, 2), min_size=1, max_size=2, unique=True))
            new, _ = data.draw(poses(count=len(ids)))
            attempt(lambda: vog.set_poses(ids, new), ["ids", "poses"], None, "either", "VogMap.set_poses")
        else:
            i = data.draw(st.integers(0, 2))
            vog.submap(i).integrate_scan(np.zeros(3), np.random.default_rng(i).normal(size=(10, 3)))
            if owners.get(i) is vog:
                # its old contribution cannot be undone any more: moving it and updating is refused
                moved = vog.pose(i) @ vj.geometry.exp_se3(np.array([0, 0, 0.3, 0.5, 0, 0]))
                vog.set_poses([i], moved[None])
                attempt(
                    lambda: g.update_poses(vog, None, **{k: 0.0 for k in thresholds}),
                    ["vog"],
                    snapshot,
                    "invalid",
                    "GlobalMap.update_poses (changed submap)",
                )
                g.merge(vog)
                owners, applied = {k: vog for k in range(3)}, {k: vog.pose(k) for k in range(3)}
        assert g.applied_ids == tuple(sorted(owners))
        assert all(np.array_equal(g.applied_pose(i), applied[i]) for i in owners)
        assert sums_dict(g) == reference_sums(CFG, owners, applied)
        _, _, counts = g.sums()
        assert np.all(counts > 0) and np.all(counts <= len(owners))


# ------------------------------------------------------------------------------ ConfidenceMap

CRM_CFG = vj.CrmConfig(voxel_size=0.25, max_range=3.0, range_sigma_m=0.1)


def crm_base():
    crm = vj.ConfidenceMap(CRM_CFG)
    rng = np.random.default_rng(5)
    crm.integrate_scans(rng.uniform(-0.5, 0.5, (2, 3)), rng.normal(size=(30, 3)) * 1.5, np.repeat([0, 1], 15))
    return crm


def crm_points_valid(origin, points, cfg=CRM_CFG) -> bool:
    o = np.asarray(origin, np.float64).reshape(-1, 3)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    return not np.any(np.all(p.astype(np.float32) == o.astype(np.float32)[:1], axis=1)) if len(o) else True


@fuzz(40)
@given(data=st.data())
def test_confidence_map_integrate(warm, data):
    """integrate_scan / integrate_scans, valid or hostile: a batch gives the map, bit for bit, of
    the scans one by one; moments stay in range; a refused call changes nothing."""
    crm, twin = crm_base(), crm_base()
    offset = data.draw(OFFSETS)
    origin, e1 = data.draw(hostile_array((3,), vector3(-0.5, 0.5).map(lambda v: v + offset), allow_empty=False))
    points, e2 = data.draw(hostile_array((-1, 3), points_array(0, 10).map(lambda p: p + offset)))
    if e2 == "valid" and data.draw(st.booleans()) and np.size(points):
        points = np.asarray(points, np.float64) * data.draw(st.sampled_from([10.0, 1e4, 1e6, 3e6]))
        e2 = "valid" if in_key_range(points, CRM_CFG.voxel_size) else "either"
    expect = "invalid" if "invalid" in (e1, e2) else "valid" if e1 == e2 == "valid" else "either"
    if expect == "valid" and not crm_points_valid(origin, points):
        expect = "invalid"  # a beam needs a direction
    batch = data.draw(st.booleans())
    if batch:
        try:
            count = np.shape(points)[0] if np.ndim(points) else 0
        except ValueError:  # ragged
            count = 0
        call = lambda: crm.integrate_scans(
            np.asarray(origin)[None] if isinstance(origin, np.ndarray) else [origin], points, np.zeros(count, np.int64)
        )
    else:
        call = lambda: crm.integrate_scan(origin, points)
    result = attempt(
        call,
        ["origin", "points", "scan_index"],
        crm.voxels,
        expect,
        "ConfidenceMap.integrate_scans" if batch else "ConfidenceMap.integrate_scan",
    )
    if result is REFUSED:
        return
    twin.integrate_scan(np.asarray(origin, np.float64), np.asarray(points, np.float64).reshape(-1, 3))
    assert same(crm.voxels(), twin.voxels())
    _, mean, variance = crm.voxels()
    assert np.all((mean >= 0) & (mean <= 1)) and np.all(variance >= 0) and np.all(variance <= 0.25)


@fuzz(40)
@given(data=st.data())
def test_confidence_map_queries(warm, data):
    """mean, variance, state, observed, distribution and raycast: well-formed, the prior where
    unknown, and equal to the stored voxels where known."""
    crm = crm_base()
    centres, stored_mean, _ = crm.voxels()
    op = data.draw(st.sampled_from(["points", "points", "rays"]))
    if op == "points":
        points, expect = data.draw(hostile_array((-1, 3), points_array(0, 10, -4.0, 4.0)))
        if expect == "valid" and data.draw(st.booleans()):
            points = np.concatenate([np.asarray(points, np.float64).reshape(-1, 3), centres[:3]])
        for name in ("mean", "variance", "state", "observed", "distribution"):
            result = attempt(
                lambda: getattr(crm, name)(points), ["points"], crm.voxels, expect, f"ConfidenceMap.{name}"
            )
            if result is REFUSED:
                continue
            p = np.asarray(points, np.float64).reshape(-1, 3)
            keys = np.floor(p.astype(np.float32).astype(np.float64) / CRM_CFG.voxel_size).astype(np.int64)
            known = {
                tuple(k): v
                for k, v in zip(np.floor(centres / CRM_CFG.voxel_size).astype(np.int64).tolist(), stored_mean)
            }
            means = np.array([known.get(tuple(k), np.nan) for k in keys.tolist()], np.float32)
            if name == "mean":
                assert np.array_equal(result, np.where(np.isnan(means), CRM_CFG.prior_mean, means))
            elif name == "observed":
                assert np.array_equal(result, ~np.isnan(means))
            elif name == "variance":
                assert result.shape == (len(p),) and np.all((result >= 0) & (result <= 0.25))
            elif name == "distribution":
                assert result.shape == (len(p), CRM_CFG.num_bins)
                np.testing.assert_allclose(result.sum(axis=1), 1.0, atol=1e-4)
            else:
                assert result.shape == (len(p),) and set(result.tolist()) <= {0, 1, 2}
    else:
        origins, directions, max_range, expect = data.draw(ray_arguments(4))
        if expect == "valid":
            expect = "either"  # ranges reaching past the key range are refused by this map
        result = attempt(
            lambda: crm.raycast(origins, directions, max_range),
            ["origins", "directions", "max_range"],
            crm.voxels,
            expect,
            "ConfidenceMap.raycast",
        )
        if result is not REFUSED:
            n = np.shape(origins)[0]
            ranges = np.broadcast_to(np.asarray(max_range, np.float64), (n,))
            assert result.hit.shape == (n,) and np.all(result.distance <= ranges.astype(np.float32))
            assert np.all((result.reach_probability >= 0) & (result.reach_probability <= 1))
            assert np.all(result.variance_max <= 0.25 + 1e-6) and np.all(result.num_unknown >= 0)


CRM_FIELDS = {
    "voxel_size": st.sampled_from([0.1, 1e-4, 0.0, 1e300, 1000.0, 1000.5]),
    "max_range": st.sampled_from([11.0, 0.0, 1e300, 7.2e7, 409.6, 409.7]),
    "range_sigma_m": st.sampled_from([0.05, 0.0, 1e300, 1e-300]),
    "cause_range": st.sampled_from(["chord", "centre", "center", ""]),
    "num_bins": st.sampled_from([16, 2, 1, 64, 65, 16.0]),
    "spurious_probability": st.sampled_from([0.0, 0.5, 1.0, -0.1]),
    "cone_sigmas": st.sampled_from([3.0, 0.5, 0.4, 10.0, 11.0]),
    "bin_floor": st.sampled_from([1e-6, 0.0, 0.01, 0.02, 0.03]),
    "occupied_threshold": st.sampled_from([0.7, 0.3, 1.0]),
    "free_threshold": st.sampled_from([0.3, 0.7, 0.0]),
}


def crm_rules_hold(f: dict) -> bool:
    return (
        1e-4 <= f["voxel_size"] <= 1000
        and 0 < f["max_range"] <= MAX_RANGE_VOXELS * f["voxel_size"]
        and f["range_sigma_m"] > 0
        and f["cause_range"] in ("chord", "centre")
        and isinstance(f["num_bins"], int)
        and 2 <= f["num_bins"] <= 64
        and 0 <= f["spurious_probability"] < 1
        and 0.5 <= f["cone_sigmas"] <= 10
        and 0 < f["bin_floor"] <= 0.01
        and 0 < f["occupied_threshold"] < 1
        and 0 < f["free_threshold"] < 1
        and f["free_threshold"] <= f["occupied_threshold"]
        and f["bin_floor"] * f["num_bins"] < 0.5
    )


@fuzz(100)
@given(data=st.data())
def test_crm_config(data):
    fields = {name: data.draw(strategy) for name, strategy in CRM_FIELDS.items() if data.draw(st.integers(0, 2)) > 0}
    full = {f: getattr(vj.CrmConfig, f) for f in CRM_FIELDS} | fields
    valid = crm_rules_hold(full)
    config = attempt(
        lambda: vj.CrmConfig(**fields),
        [f"CrmConfig.{f}" for f in CRM_FIELDS],
        expect="valid" if valid else "invalid",
        what="CrmConfig",
    )
    if config is not REFUSED:
        assert all(getattr(config, f) == v for f, v in full.items())


# ------------------------------------------------------------------------------ documented limits


def test_confidence_map_refuses_rays_leaving_the_key_range():
    """A confidence-rich map walks every voxel of a ray, so it refuses ranges that leave the key
    range; the occupancy maps accept any range and count long unknown stretches in closed form."""
    with pytest.raises(ValueError, match="max_range"):
        crm_base().raycast(np.zeros((1, 3)), [[1.0, 0, 0]], 1e300)
    vmap, cells = base_map()
    r = vmap.raycast(np.zeros((1, 3)), [[1.0, 0, 0]], 1e300)
    assert not r.hit[0] and r.num_unknown[0] > 0


# ------------------------------------------------------------------------------ findings, fixed (regression tests)


def refuses(call, name: str = "") -> None:
    """AssertionError unless `call()` raises a ValueError naming `name`."""
    try:
        call()
    except ValueError as error:
        assert name in str(error), f"{error!r} does not name {name!r}"
        return
    raise AssertionError("accepted")


COMPLEX_POSE = np.eye(4) + 1e-3j  # a rigid real part: the imaginary part is silently dropped


@pytest.mark.parametrize(
    "call",
    [
        lambda: vj.VogMap(CFG).add_submap(COMPLEX_POSE),
        lambda: vj.VogMap(CFG).add_submap(np.eye(4).astype(str)),
        lambda: random_vog(1).set_poses([0], COMPLEX_POSE[None]),
        lambda: vj.GlobalMap(CFG).merge(random_vog(1), np.eye(6)[None] * (1 + 5j)),
    ],
    ids=["add_submap-complex", "add_submap-strings", "set_poses-complex", "merge-complex-marginals"],
)
def test_complex_and_text_arrays_are_refused(call):
    refuses(call)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: base_map()[0].integrate_scans(np.zeros((2, 3)), np.ones((2, 3)), RAGGED), "scan_index"),
        (lambda: crm_base().integrate_scans(np.zeros((2, 3)), np.ones((2, 3)), RAGGED), "scan_index"),
        (lambda: random_vog(2).poses([[0], [0, 1]]), "ids"),
        (lambda: random_vog(2).set_poses([[0], [0, 1]], np.eye(4)[None]), "ids"),
    ],
    ids=["VoxelMap.integrate_scans", "ConfidenceMap.integrate_scans", "VogMap.poses", "VogMap.set_poses"],
)
def test_ragged_ids_are_refused_naming_the_argument(call, name):
    refuses(call, name)


def test_an_empty_pose_stack_is_not_a_pose():
    vog = vj.VogMap(CFG)
    try:
        refuses(lambda: vog.add_submap(np.zeros((0, 4, 4))), "pose")
    finally:
        assert vog.num_submaps == len(vog.poses()), "a submap without a pose was added"


def test_readers_are_not_starved_by_writers_taking_turns():
    import threading

    from vogjax.maps.locking import ReadWriteLock

    lock = ReadWriteLock()
    stop = threading.Event()

    def write():
        while not stop.is_set():
            with lock.writing():
                time.sleep(0.005)  # an update: the GIL is free meanwhile

    writers = [threading.Thread(target=write, daemon=True) for _ in range(2)]
    for writer in writers:
        writer.start()
    timer = threading.Timer(2.0, stop.set)  # the writers stop after 2 s whatever happens
    try:
        time.sleep(0.1)
        timer.start()
        start = time.perf_counter()
        with lock.reading():
            waited = time.perf_counter() - start
    finally:
        timer.cancel()
        stop.set()
        for writer in writers:
            writer.join()
    assert waited < 1.0, f"a reader waited {waited:.1f} s for two writers taking turns"
