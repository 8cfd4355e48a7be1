"""Integration of the confidence-rich map (Agha-mohammadi's sensor cause model, Eqs. 14-27).

Each voxel holds a distribution over its occupancy level m at num_bins points m_k = k/(K-1)
(a vector layer), its mean and variance (scalar layers, NaN while never observed) and a
"pending" byte. A beam is the ray from the sensor along the reading; its *cone* is every voxel
it passes with a chord longer than MIN_CHORD_EDGES voxel edges (traversal.py: not one it only
touches at an edge or a corner), from the sensor out to the reading plus cone_sigmas
standard deviations (to max_range for a beam without a return). Along the cone, with m^_c the
mean of voxel c before the scan:

    bounce  B_c = m^_c                        reach  T_c = prod_{l<c} (1 - m^_l)     (Eqs. 15-16)
    likelihood of the reading if c caused it, L_c (Eq. 18): for a return at range z, the
    N(z; t, sigma^2) density averaged over the chord [t_in, t_out] (the bounce is anywhere on
    it), or at t = the distance of the voxel's centre (cause_range "centre", the paper's form);
    without a return, P(t + noise > max_range), t the chord's middle or the centre. The noise
    is cut off at NOISE_CUTOFF sigma. The cause at infinity (nothing bounced within reach)
    explains only "no return" (L = 1); a spurious reading (probability p_s) explains only
    returns, L_s = 1/max_range.

The update of voxel i (Eqs. 21-25) multiplies its distribution by the likelihood of the reading
as a function of m^i with every other voxel at its mean, which is linear in m^i:

    f(m) = (1 - m) f0 + m f1,   f0 = (1-p_s)(P_i + T_i S_i) + p_s L_s,
                                f1 = (1-p_s)(P_i + T_i L_i) + p_s L_s,
    P_i = sum_{c<i} L_c m^_c T_c               (caused before i: the ratio 1 in Eq. 22)
    S_i = sum_{c>i} L_c m^_c prod_{i<l<c}(1-m^_l) + L_inf prod_{l>i}(1-m^_l)   (caused beyond i)

f divided by its mean under the voxel's distribution is the paper's alpha m + beta; we divide
by max(f0, f1) instead (the scan's final renormalisation removes any constant), so the factors
lie in [0, 1] and nothing overflows. S comes from one backward pass over the cone, P and T from
one forward pass: no division by m^ or 1 - m^ anywhere.

A scan: every beam's factors are computed from the means before the scan; each voxel then
multiplies in the factors of the beams that cross it in beam order (the host orders a scan's
beams by their endpoints), rescaling if they fall towards underflow. A factor of exactly
(1, 0), f(m) = 1 - m (a beam passing long before its reading: L = 0 up to there, so P = 0 and
f1 = 0), is a free pass: only counted, and the count's power of 1 - m_k applied at the end of
the scan, before the voxel is renormalised, floored at bin_floor, renormalised again, and gets
its new mean and variance (a batch of many scans computes the variances once at its end
instead: the same bits).
On the CPU one sequential launch does a whole pass of scans in order; on CUDA the factors are
computed in parallel and a stable sort by voxel replays each voxel's factors in beam order. The
two give the same bits.
"""

import functools
import math
import types

import numpy as np
import warp as wp

from .hashing import BLOCK_VOXELS, EMPTY_KEY, block_of, find_voxel_slot, hash_key, index_in_block, observed, pack_block
from .traversal import FAR, first_boundary, holds_chord, ray_walk_begin, voxel_key, walk_step

wp.set_module_options({"enable_backward": False})

INV_SQRT2 = wp.constant(wp.float64(1.0 / math.sqrt(2.0)))
INV_SQRT_2PI = wp.constant(wp.float64(1.0 / math.sqrt(2.0 * math.pi)))
# A chord shorter than this many sigma takes the density at its middle: the averaged form
# would divide a difference of nearly equal CDFs by nearly nothing.
SHORT_CHORD_SIGMAS = wp.constant(wp.float64(1.0e-3))
# The range noise is taken as exactly zero beyond this many sigma (its tail there is 6e-16).
NOISE_CUTOFF = wp.constant(wp.float64(8.0))
# A chord ending this many sigma before a reading is past NOISE_CUTOFF whatever the rounding.
FAR_SIGMAS = wp.constant(wp.float64(8.0001))
# Bins are scaled back up when the largest falls below this mid-scan (many beams in one scan).
RESCALE_BELOW = wp.constant(wp.float32(1.0e-20))
# Below this a largest bin is scaled by TWO_TO_100 first (1 / it would overflow float32).
TINY = wp.constant(wp.float32(1.0e-37))
SMALLEST_NORMAL = wp.constant(wp.float32(np.finfo(np.float32).tiny))
TWO_TO_100 = wp.constant(wp.float32(2.0**100))


# ---------------------------------------------------------------- geometry of the cones
@wp.func
def tail(u: wp.float64) -> wp.float64:
    """P(N(0,1) beyond |u| on u's side); 0 past NOISE_CUTOFF (the noise is cut off there)."""
    a = wp.abs(u)
    if a >= NOISE_CUTOFF:
        return wp.float64(0.0)
    return wp.float64(0.5) * wp.erfc(a * INV_SQRT2)


@wp.func
def cdf_difference(a: wp.float64, tail_a: wp.float64, b: wp.float64, tail_b: wp.float64) -> wp.float64:
    """Phi(b) - Phi(a) for a < b from the tails at a and b (no cancellation in either tail)."""
    if a > wp.float64(0.0):
        return tail_a - tail_b
    if b <= wp.float64(0.0):
        return tail_b - tail_a
    return wp.float64(1.0) - tail_a - tail_b


@wp.func
def density(u: wp.float64, sigma: wp.float64) -> wp.float64:
    """N(0,1) density at u over sigma: the noise density of a reading u sigma off."""
    if wp.abs(u) >= NOISE_CUTOFF:
        return wp.float64(0.0)
    return wp.exp(wp.float64(-0.5) * u * u) * INV_SQRT_2PI / sigma


@wp.func
def chord_likelihood(
    u_in: wp.float64,
    tail_in: wp.float64,
    u_out: wp.float64,
    tail_out: wp.float64,
    length: wp.float64,
    sigma: wp.float64,
) -> wp.float64:
    """L_c of a return with the bounce anywhere on the chord: the noise density averaged over
    it, u = (z - t) / sigma at its ends (u_out < u_in)."""
    if length < SHORT_CHORD_SIGMAS * sigma:
        return density(wp.float64(0.5) * (u_in + u_out), sigma)
    return cdf_difference(u_out, tail_out, u_in, tail_in) / length


@wp.func
def no_return_likelihood(t_cause: wp.float64, sigma: wp.float64, max_range: wp.float64) -> wp.float64:
    """L_c of "no return": the reading from range t_cause lands past max_range."""
    v = (t_cause - max_range) / sigma
    if v <= wp.float64(0.0):
        return tail(v)
    return wp.float64(1.0) - tail(v)


@wp.func
def centre_distance(voxel: wp.vec3i, origin: wp.vec3d, resolution: wp.float64) -> wp.float64:
    half = wp.float64(0.5)
    c = wp.vec3d(
        (wp.float64(voxel[0]) + half) * resolution - origin[0],
        (wp.float64(voxel[1]) + half) * resolution - origin[1],
        (wp.float64(voxel[2]) + half) * resolution - origin[2],
    )
    return wp.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])


@wp.func
def planes_after(t: wp.float64, delta: wp.float64, planes: int, length: wp.float64):
    """The distance `planes` voxel planes further along an axis, summed one plane at a time as
    walk_step sums it (so it has the voxel walk's bits), and how many of the distances passed
    on the way (t included, the result not) lie before `length`."""
    before = int(0)
    for _ in range(planes):
        before += wp.where(t < length, 1, 0)
        t = t + delta
    return t, before


@wp.kernel
def list_cone_blocks(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    lengths: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    recent: wp.array(dtype=wp.int64),
    block_keys: wp.array2d(dtype=wp.int64),
    block_counts: wp.array(dtype=wp.int32),
    step_bounds: wp.array(dtype=wp.int32),
):
    """Per beam: the blocks its cone's voxels lie in, in walk order, and a bound on how many
    voxels the cone has (exact unless two axes cross voxel planes at the same distance).
    block_keys[tid, n] holds the n-th block, or EMPTY_KEY where `recent` (a small table of
    blocks listed lately, by a hash of the block, EMPTY_KEY at first) holds it: another beam
    listed it (neighbouring beams cross the same blocks), so the host need not sort it again.

    Walks block by block. Along each axis the distance to every voxel plane is summed one plane
    at a time from the voxel walk's start, exactly as walk_step sums it, so every block plane
    lies where the voxel walk meets it: a block is listed iff the voxel walk (fill_cone_steps)
    spends more than MIN_CHORD_EDGES voxel edges in it before the cone's end, so every block
    holding a cone voxel is listed (and, where only slivers share such a span, one holding none:
    allocated, left at the prior). The voxel walk takes one step per
    voxel plane before the end, plus one: that count is the bound."""
    tid = wp.tid()
    length = lengths[tid]
    w = ray_walk_begin(origins[tid], directions[tid], resolution, inv_resolution, length)
    capacity = block_keys.shape[1]
    planes = int(1)  # voxel planes before the end, plus one
    block_plane = wp.vec3d(FAR, FAR, FAR)  # per axis: where the walk next enters another block
    for axis in range(3):
        if w.step[axis] != 0:
            inside = w.voxel[axis] & 7  # voxel planes before the block's own: 7 - inside going up
            if w.step[axis] > 0:
                inside = 7 - inside
            t, before = planes_after(w.t_max[axis], w.t_delta[axis], inside, length)
            block_plane[axis] = t
            planes += before
    block = block_of(w.voxel)
    n_blocks = int(0)
    t_in = wp.float64(0.0)
    moves = int(0)
    while t_in < length and moves <= w.max_steps:
        if holds_chord(t_in, first_boundary(block_plane, length), resolution):
            if n_blocks < capacity:
                key = pack_block(block)
                r = int(hash_key(key) & wp.uint32(recent.shape[0] - 1))
                if recent[r] == key:
                    key = EMPTY_KEY
                else:
                    recent[r] = key
                block_keys[tid, n_blocks] = key
            n_blocks += 1
        # the axis whose block plane comes first; on a tie the block between lasts no distance
        # and is not listed, so the order does not matter
        axis = int(2)
        if block_plane[0] < block_plane[1] and block_plane[0] < block_plane[2]:
            axis = 0
        elif block_plane[1] < block_plane[2]:
            axis = 1
        t_in = block_plane[axis]
        block[axis] = block[axis] + w.step[axis]
        t, before = planes_after(t_in, w.t_delta[axis], 8, length)
        block_plane[axis] = t
        planes += before
        moves += 1
    block_counts[tid] = n_blocks  # above the capacity: the host lists again with more room
    for n in range(n_blocks, capacity):
        block_keys[tid, n] = EMPTY_KEY
    # every block plane now lies at or past the end, so every plane before it was counted
    # (but if the walk gave up, which it never does: then the voxel walk's most)
    if t_in < length:
        planes = w.max_steps + 1
    step_bounds[tid] = planes


@wp.kernel
def fill_cone_steps(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    lengths: wp.array(dtype=wp.float64),
    ranges: wp.array(dtype=wp.float64),
    returned: wp.array(dtype=wp.int32),
    first_step: wp.array(dtype=wp.int32),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    sigma: wp.float64,
    max_range: wp.float64,
    at_centre: int,
    table_keys: wp.array(dtype=wp.int64),
    table_slots: wp.array(dtype=wp.int32),
    step_voxel: wp.array(dtype=wp.int32),
    step_likelihood: wp.array(dtype=wp.float64),
    filled: wp.array(dtype=wp.int32),
    band_start: wp.array(dtype=wp.int32),
):
    """Per beam, its cone's blocks listed by `list_cone_blocks`: each cone voxel's index in the
    voxel pool and its likelihood L_c, at the beam's steps [first_step[tid], first_step[tid + 1])
    (room for list_cone_blocks' bound); `filled` counts those written, `band_start` those before
    the first nonzero likelihood (the reading's noise band; `filled` if none).
    at_centre: a cause's range is the distance to its voxel's centre (the paper's Eq. 18), not
    spread over its chord."""
    tid = wp.tid()
    origin = origins[tid]
    length = lengths[tid]
    z = ranges[tid]
    hit = returned[tid] != 0
    w = ray_walk_begin(origin, directions[tid], resolution, inv_resolution, length)
    n = first_step[tid]
    end = first_step[tid + 1]
    voxel, t_max, t_in = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    slot = int(-1)
    missing = int(0)
    new_block = bool(True)
    steps = int(0)
    # Chord ends as u = (z - t) / sigma, each boundary's tail computed once, from the first
    # step that ends within FAR_SIGMAS of the reading: before it every u is at least
    # NOISE_CUTOFF, so every likelihood exactly 0 (what the formulas give there), unwritten.
    far_until = z - FAR_SIGMAS * sigma
    near = bool(False)
    u_in = wp.float64(0.0)
    tail_in = wp.float64(0.0)
    band = int(-1)
    while t_in < length and steps <= w.max_steps:
        if new_block:
            slot = find_voxel_slot(table_keys, table_slots, voxel)
        t_out = first_boundary(t_max, length)
        in_cone = holds_chord(t_in, t_out, resolution)
        if in_cone and n >= end:
            missing = 1  # more voxels than the listing's bound: never; the host raises
        if not in_cone:
            near = False  # a sliver at an edge or a corner, left out: the next chord's tail afresh
        elif n < end:
            if slot < 0:  # a block the listing missed: never (list_cone_blocks); the host raises
                missing = 1
            step_voxel[n] = wp.max(slot, 0) * BLOCK_VOXELS + index_in_block(voxel)
            if at_centre != 0:
                t_cause = centre_distance(voxel, origin, resolution)
                if hit:
                    step_likelihood[n] = density((z - t_cause) / sigma, sigma)
                else:
                    step_likelihood[n] = no_return_likelihood(t_cause, sigma, max_range)
            elif hit:
                if t_out <= far_until:
                    step_likelihood[n] = wp.float64(0.0)
                else:
                    if not near:
                        u_in = (z - t_in) / sigma
                        tail_in = tail(u_in)
                        near = True
                    u_out = (z - t_out) / sigma
                    tail_out = tail(u_out)
                    step_likelihood[n] = chord_likelihood(u_in, tail_in, u_out, tail_out, t_out - t_in, sigma)
                    u_in = u_out
                    tail_in = tail_out
            else:
                step_likelihood[n] = no_return_likelihood(wp.float64(0.5) * (t_in + t_out), sigma, max_range)
            if band < 0 and step_likelihood[n] != wp.float64(0.0):
                band = n
            n += 1
        voxel, t_max, t_in, new_block = walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
    filled[tid] = n - first_step[tid]
    if band < 0:
        band = n
    band_start[tid] = band - first_step[tid]
    if missing != 0:
        filled[tid] = -1


@wp.kernel
def compact_cone_steps(
    first_step: wp.array(dtype=wp.int32),
    filled: wp.array(dtype=wp.int32),
    new_first_step: wp.array(dtype=wp.int32),
    step_voxel: wp.array(dtype=wp.int32),
    step_likelihood: wp.array(dtype=wp.float64),
    out_voxel: wp.array(dtype=wp.int32),
    out_likelihood: wp.array(dtype=wp.float64),
):
    """Per beam: its filled steps moved back to back, from first_step[tid] to new_first_step[tid]."""
    tid = wp.tid()
    source = first_step[tid]
    target = new_first_step[tid]
    for i in range(filled[tid]):
        out_voxel[target + i] = step_voxel[source + i]
        out_likelihood[target + i] = step_likelihood[source + i]


# ---------------------------------------------------------------- the sensor cause model
@wp.func
def mean_or_prior(mean: wp.array(dtype=wp.float32), voxel: int, prior_mean: wp.float32) -> wp.float32:
    m = mean[voxel]
    if not observed(m):
        return prior_mean
    return m


@wp.func
def beam_tails(
    lo: int,
    hi: int,
    tail: wp.float64,
    step_voxel: wp.array(dtype=wp.int32),
    step_likelihood: wp.array(dtype=wp.float64),
    mean: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    base: int,
    step_mean: wp.array(dtype=wp.float32),
    step_tail: wp.array(dtype=wp.float64),
) -> wp.float64:
    """Backward over steps [lo, hi) of a beam's cone, `tail` the likelihood of the reading caused
    beyond step hi - 1: each voxel's mean before the scan and S_i, the likelihood of the reading
    caused beyond it, at scratch index i - base. Returns S_{lo - 1}."""
    for back in range(hi - lo):
        i = hi - 1 - back
        m = mean_or_prior(mean, step_voxel[i], prior_mean)
        step_mean[i - base] = m
        step_tail[i - base] = tail
        m64 = wp.float64(m)
        tail = step_likelihood[i] * m64 + (wp.float64(1.0) - m64) * tail
    return tail


@wp.func
def tail_beyond_cone(hit: bool) -> wp.float64:
    """S past a cone's last voxel: a return cannot come from beyond it; "no return" comes from
    the cause at infinity."""
    if hit:
        return wp.float64(0.0)
    return wp.float64(1.0)


@wp.func
def spurious_term(hit: bool, spurious: wp.float64, spurious_likelihood: wp.float64) -> wp.float64:
    if hit:
        return spurious * spurious_likelihood
    return wp.float64(0.0)  # a spurious reading is always a return


@wp.func
def cause_factor(
    likelihood: wp.float64,
    tail: wp.float64,
    before: wp.float64,
    reach: wp.float64,
    keep: wp.float64,
    floor_term: wp.float64,
) -> wp.vec2f:
    """(r0, r1): the reading's likelihood if the voxel were empty, full, over the larger one."""
    f0 = keep * (before + reach * tail) + floor_term
    f1 = keep * (before + reach * likelihood) + floor_term
    if f0 >= f1:
        if f0 > wp.float64(0.0) and f0 < wp.float64(1.0e300):
            if f1 == wp.float64(0.0):  # most steps: the beam passes long before its reading
                return wp.vec2f(wp.float32(1.0), wp.float32(0.0))
            return wp.vec2f(wp.float32(1.0), wp.float32(f1 / f0))
        return wp.vec2f(wp.float32(1.0), wp.float32(1.0))  # the map deems the reading impossible
    if f1 < wp.float64(1.0e300):
        return wp.vec2f(wp.float32(f0 / f1), wp.float32(1.0))
    return wp.vec2f(wp.float32(1.0), wp.float32(1.0))


@wp.kernel
def compute_beam_factors(
    first_beam: int,
    beam_first_step: wp.array(dtype=wp.int32),
    returned: wp.array(dtype=wp.int32),
    step_voxel: wp.array(dtype=wp.int32),
    step_likelihood: wp.array(dtype=wp.float64),
    mean: wp.array(dtype=wp.float32),
    prior_mean: wp.float32,
    spurious: wp.float64,
    spurious_likelihood: wp.float64,
    step_mean: wp.array(dtype=wp.float32),
    step_tail: wp.array(dtype=wp.float64),
    step_factor: wp.array(dtype=wp.vec2f),
):
    """The factors of beams first_beam + tid (one scan's beams: they all read the means before it)."""
    tid = wp.tid()
    beam = first_beam + tid
    lo = beam_first_step[beam]
    hi = beam_first_step[beam + 1]
    hit = returned[beam] != 0
    beam_tails(lo, hi, tail_beyond_cone(hit), step_voxel, step_likelihood, mean, prior_mean, 0, step_mean, step_tail)
    keep = wp.float64(1.0) - spurious
    floor_term = spurious_term(hit, spurious, spurious_likelihood)
    before = wp.float64(0.0)  # P_i: the reading caused before voxel i
    reach = wp.float64(1.0)  # T_i
    for i in range(lo, hi):
        m64 = wp.float64(step_mean[i])
        likelihood = step_likelihood[i]
        step_factor[i] = cause_factor(likelihood, step_tail[i], before, reach, keep, floor_term)
        before = before + likelihood * m64 * reach
        reach = reach * (wp.float64(1.0) - m64)


@wp.kernel
def sort_keys_of_steps(
    step_voxel: wp.array(dtype=wp.int32), keys: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)
):
    tid = wp.tid()
    keys[tid] = step_voxel[tid]
    order[tid] = tid


@wp.kernel
def flag_scan_groups(
    keys: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    step_scan: wp.array(dtype=wp.int32),
    no_group: int,
    group_scan: wp.array(dtype=wp.int32),
    group_entry: wp.array(dtype=wp.int32),
    scan_groups: wp.array(dtype=wp.int32),
):
    """A pass's steps sorted (stably) by voxel: the first entry of each (voxel, scan) run starts a
    group, keyed by its scan (no_group for the other entries, which sort after every scan);
    scan_groups counts each scan's groups."""
    tid = wp.tid()
    scan = step_scan[order[tid]]
    start = tid == 0
    if not start:
        start = keys[tid - 1] != keys[tid] or step_scan[order[tid - 1]] != scan
    group_entry[tid] = tid
    if start:
        group_scan[tid] = scan
        wp.atomic_add(scan_groups, scan, 1)
    else:
        group_scan[tid] = no_group


# ---------------------------------------------------------------- per number of bins
@functools.cache
def for_bins(num_bins: int) -> types.SimpleNamespace:
    """The kernels over distributions of `num_bins` bins (one compiled module per bin count)."""
    K = int(num_bins)
    module = f"vogjax.kernels.confidence_bins_{K}"  # one module (one compile) per bin count
    Bins = wp.types.vector(length=K, dtype=wp.float32)
    Bins64 = wp.types.vector(length=K, dtype=wp.float64)
    last = float(K - 1)

    levels = np.arange(K, dtype=np.float32) / np.float32(last)
    LEVELS = Bins(*levels.tolist())
    ONES = Bins(*([1.0] * K))
    QUADS, REST = K // 4, K % 4
    # Most cone steps are free passes, f(m) = 1 - m. A voxel counts them (in its pending byte
    # on the CPU, up to MOST_FREE_PASSES) and takes their product (1 - m_k)^n before its next
    # other factor, or at the scan's end, FREE_CHUNK passes at a time from a table of powers
    # computed in float64 (passed_freely). A chunk scales no bin but the last below
    # (1/(K-1))^FREE_CHUNK >= 1e-15.
    passed = 1.0 - levels.astype(np.float64)
    FREE_CHUNK = max(1, min(64, int(15.0 / math.log10(last)))) if K > 2 else 64
    PREFETCH_VOXELS = 16
    MOST_FREE_PASSES = 254  # pending counts 1 + the passes
    free_powers = passed[None, :] ** np.arange(FREE_CHUNK + 1)[:, None]

    @wp.func
    def bin_sum(b: Bins) -> wp.float32:
        """The sum of the bins in four interleaved running sums, added pairwise at the end: a
        fixed order (both paths of a device give the same bits) with a quarter of the dependent
        additions of one running sum, which made the end-of-scan renormalisation a third of the
        update."""
        p = wp.vec4f(wp.float32(0.0))
        for j in range(QUADS):
            p = p + wp.vec4f(b[4 * j], b[4 * j + 1], b[4 * j + 2], b[4 * j + 3])
        for k in range(REST):
            p[k] = p[k] + b[4 * QUADS + k]
        return (p[0] + p[1]) + (p[2] + p[3])

    @wp.func
    def scaled(b: Bins, factor: Bins) -> Bins:
        """Bins times `factor` (one value per level), kept away from underflow."""
        b = wp.cw_mul(b, factor)
        # the 16-way max only when neither end bin clears the threshold (the same test, and
        # the same bits, at half the cost of the update: rescaling is rare)
        if b[0] < RESCALE_BELOW and b[K - 1] < RESCALE_BELOW:
            top = wp.max(b)
            if top < RESCALE_BELOW and top > wp.float32(0.0):
                if top < TINY:  # 1 / top would overflow: first an exact power of two
                    b = b * TWO_TO_100
                    top = top * TWO_TO_100
                b = b * (wp.float32(1.0) / top)
        return b

    @wp.func
    def apply_factor(bins: wp.array(dtype=Bins), voxel: int, r: wp.vec2f):
        """Multiply a voxel's bins by f(m_k) = r0 + m_k (r1 - r0)."""
        bins[voxel] = scaled(bins[voxel], ONES * r[0] + LEVELS * (r[1] - r[0]))

    @wp.func
    def passes_freely(r: wp.vec2f) -> bool:
        """The factor of a beam that passes the voxel long before its reading: f(m) = 1 - m."""
        return r[0] == wp.float32(1.0) and r[1] == wp.float32(0.0)

    @wp.func
    def passed_freely(b: Bins, free_powers: wp.array(dtype=Bins64), n: int) -> Bins:
        """Bins times (1 - m_k)^n, FREE_CHUNK passes at a time. While bin 0 clears RESCALE_BELOW
        in float32; else in float64, rescaled to a top bin of 1 whenever it falls below
        RESCALE_BELOW (the scan's end renormalises anyway), so that a level far below the top
        is not lost when the passes zero the top (m = 1): a voxel hundreds of a scan's
        readings ended in, then passed by."""
        if n <= 0:
            return b
        if b[0] >= RESCALE_BELOW:
            # bin 0 (m = 0) never shrinks, so the top stays at least it: in float32 the powers
            # lose nothing that passes one at a time would keep
            left = n
            while left > 0:
                chunk = wp.min(left, FREE_CHUNK)
                power = free_powers[chunk]
                single = Bins()
                for k in range(K):
                    single[k] = wp.float32(power[k])
                b = wp.cw_mul(b, single)
                left -= chunk
            return b
        x = Bins64()
        for k in range(K):  # a subnormal bin has lost its precision: 0 (as a float32 pass would make it)
            x[k] = wp.where(b[k] >= SMALLEST_NORMAL, wp.float64(b[k]), wp.float64(0.0))
        left = n
        while left > 0:
            chunk = wp.min(left, FREE_CHUNK)
            x = wp.cw_mul(x, free_powers[chunk])
            left -= chunk
            top = wp.max(x)
            if top < wp.float64(RESCALE_BELOW) and top > wp.float64(0.0):
                x = x * (wp.float64(1.0) / top)
        out = Bins()
        for k in range(K):
            out[k] = wp.float32(x[k])
        return out

    @wp.func
    def apply_free_passes(bins: wp.array(dtype=Bins), voxel: int, free_powers: wp.array(dtype=Bins64), n: int):
        bins[voxel] = passed_freely(bins[voxel], free_powers, n)

    @wp.func
    def at_least(b: Bins, floor: wp.float32) -> Bins:
        """max(b, floor) per bin for bins that are never NaN: plain selects, which the compiler
        vectorises (wp.max handles NaN one bin at a time, a third of the renormalisation)."""
        out = Bins()
        for k in range(K):
            out[k] = wp.where(b[k] < floor, floor, b[k])
        return out

    @wp.func
    def mean_of(b: Bins) -> wp.float32:
        return bin_sum(wp.cw_mul(b, LEVELS))

    @wp.func
    def moments(b: Bins) -> wp.vec2f:
        mean = mean_of(b)
        d = LEVELS - ONES * mean
        return wp.vec2f(mean, bin_sum(wp.cw_mul(b, wp.cw_mul(d, d))))

    @wp.func
    def finish_scan(
        bins: wp.array(dtype=Bins),
        voxel: int,
        free_powers: wp.array(dtype=Bins64),
        free: int,
        floor: wp.float32,
        mean: wp.array(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
        with_variance: int,
        resets: wp.array(dtype=wp.int32),
    ):
        """End of a scan for a voxel it reached: its `free` passes not yet applied, then bins to
        sum 1, none below `floor`, sum 1 again; the new mean (the next scan's beams read it),
        and the new variance if `with_variance` (else variance_of_blocks computes it from the
        same bins once the batch is in: the same bits)."""
        b = passed_freely(bins[voxel], free_powers, free)
        total = bin_sum(b)
        if total > wp.float32(0.0) and total < wp.float32(1.0e30):
            b = at_least(b * (wp.float32(1.0) / total), floor)
            b = b * (wp.float32(1.0) / bin_sum(b))
        else:
            # every bin underflowed within the scan (hundreds of its readings in one voxel, the
            # evidence's range beyond float32's): the prior, counted (the host warns); never NaN
            b = ONES * (wp.float32(1.0) / wp.float32(K))
            wp.atomic_add(resets, 0, 1)
        bins[voxel] = b
        # the variance only when asked (computed and unused, it was a sixth of this function's cycles)
        if with_variance != 0:
            mv = moments(b)
            mean[voxel] = mv[0]
            variance[voxel] = mv[1]
        else:
            mean[voxel] = mean_of(b)

    @wp.kernel(module=module)
    def integrate_in_order(
        scan_end_beam: wp.array(dtype=wp.int32),
        beam_first_step: wp.array(dtype=wp.int32),
        beam_filled: wp.array(dtype=wp.int32),
        beam_band: wp.array(dtype=wp.int32),
        returned: wp.array(dtype=wp.int32),
        step_voxel: wp.array(dtype=wp.int32),
        step_likelihood: wp.array(dtype=wp.float64),
        prior_mean: wp.float32,
        spurious: wp.float64,
        spurious_likelihood: wp.float64,
        floor: wp.float32,
        step_mean: wp.array(dtype=wp.float32),
        step_tail: wp.array(dtype=wp.float64),
        touched: wp.array(dtype=wp.int32),
        free_powers: wp.array(dtype=Bins64),
        with_variance: int,
        bins: wp.array(dtype=Bins),
        mean: wp.array(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
        pending: wp.array(dtype=wp.uint8),
        resets: wp.array(dtype=wp.int32),
    ):
        """A pass of scans, one after the other, in one thread (the CPU path): the arithmetic of
        compute_beam_factors and apply_scan_groups, in the same order per voxel. A beam's cone is
        its first beam_filled steps from beam_first_step (its room may hold more). pending[v] is 0
        for a voxel the scan has not reached, else 1 + the free passes not yet applied."""
        _tid = wp.tid()
        keep = wp.float64(1.0) - spurious
        beam = int(0)
        for scan in range(scan_end_beam.shape[0]):
            count = int(0)
            while beam < scan_end_beam[scan]:
                lo = beam_first_step[beam]
                hi = lo + beam_filled[beam]
                hit = returned[beam] != 0
                floor_term = spurious_term(hit, spurious, spurious_likelihood)
                # The cone's steps before its first nonzero likelihood (the reading's noise has
                # not reached them) are free passes, f(m) = 1 - m, when f0 = keep T_i S_i lies in
                # (0, 1e300) at each of them. With s = keep S just before the band and T the
                # reach past all of them, each f0 lies between T s and s (the product of their
                # 1 - m less one factor, times s), so T >= 1e-200 and 1e-80 <= s <= 1e299 (no
                # product near underflow, none near the top) make them all free at once: no
                # backward pass and no factor over them. They are counted as T is summed, and
                # uncounted in the rare case the bounds fail.
                band = lo + beam_band[beam]
                # one beam's scratch at a time, so it stays in the cache
                tail = beam_tails(
                    band,
                    hi,
                    tail_beyond_cone(hit),
                    step_voxel,
                    step_likelihood,
                    mean,
                    prior_mean,
                    lo,
                    step_mean,
                    step_tail,
                )
                reach = wp.float64(1.0)  # T_i
                for i in range(lo, band):
                    v = step_voxel[i]
                    m64 = wp.float64(mean_or_prior(mean, v, prior_mean))
                    reach = reach * (wp.float64(1.0) - m64)
                    p = int(pending[v])
                    # a branch, predicted not taken: without it each step's store would wait for
                    # the last step's pending load (count would carry it)
                    if p == 0:
                        touched[count] = v
                        count += 1
                        p = 1
                    if p > MOST_FREE_PASSES:  # passes of earlier beams only: this one stays undoable
                        apply_free_passes(bins, v, free_powers, MOST_FREE_PASSES)
                        p = 1
                    pending[v] = wp.uint8(p + 1)
                first = band  # the first step whose factor is computed
                s = keep * tail
                if not (
                    floor_term == wp.float64(0.0)
                    and reach >= wp.float64(1.0e-200)
                    and s >= wp.float64(1.0e-80)
                    and s <= wp.float64(1.0e299)
                ):
                    # near underflow, or spurious readings: every step's factor as it comes
                    for i in range(lo, band):
                        v = step_voxel[i]
                        pending[v] = wp.uint8(int(pending[v]) - 1)
                    beam_tails(lo, band, tail, step_voxel, step_likelihood, mean, prior_mean, lo, step_mean, step_tail)
                    reach = wp.float64(1.0)
                    first = lo
                before = wp.float64(0.0)  # P_i
                for i in range(first, hi):
                    m64 = wp.float64(step_mean[i - lo])
                    likelihood = step_likelihood[i]
                    tail = step_tail[i - lo]
                    free_pass = bool(False)
                    r = wp.vec2f(wp.float32(1.0), wp.float32(1.0))
                    if likelihood == wp.float64(0.0) and before == wp.float64(0.0) and floor_term == wp.float64(0.0):
                        f0 = keep * (reach * tail)
                        free_pass = f0 > wp.float64(0.0) and f0 < wp.float64(1.0e300)
                    else:
                        r = cause_factor(likelihood, tail, before, reach, keep, floor_term)
                        free_pass = passes_freely(r)
                    before = before + likelihood * m64 * reach
                    reach = reach * (wp.float64(1.0) - m64)
                    v = step_voxel[i]
                    p = int(pending[v])
                    if p == 0:
                        touched[count] = v
                        count += 1
                        p = 1
                    if free_pass:
                        if p > MOST_FREE_PASSES:
                            apply_free_passes(bins, v, free_powers, MOST_FREE_PASSES)
                            p = 1
                        p += 1
                    else:  # the passes counted so far go first: factors keep their order
                        if p > 1:
                            apply_free_passes(bins, v, free_powers, p - 1)
                            p = 1
                        apply_factor(bins, v, r)
                    pending[v] = wp.uint8(p)
                beam += 1
            early = wp.float32(0.0)
            for t in range(count):
                # the bins of a voxel PREFETCH_VOXELS ahead, read now: most are not in the cache
                # (free passes only counted them), and their misses then overlap this one's work
                if t + PREFETCH_VOXELS < count:
                    early = early + bins[touched[t + PREFETCH_VOXELS]][0]
                v = touched[t]
                finish_scan(bins, v, free_powers, int(pending[v]) - 1, floor, mean, variance, with_variance, resets)
                pending[v] = wp.uint8(0)
            if early < wp.float32(0.0):  # never: bins are not negative (keeps the reads)
                step_mean[0] = early

    @wp.kernel(module=module)
    def apply_scan_groups(
        scan: int,
        first_group: wp.array(dtype=wp.int32),
        group_entry: wp.array(dtype=wp.int32),
        keys: wp.array(dtype=wp.int32),
        order: wp.array(dtype=wp.int32),
        step_scan: wp.array(dtype=wp.int32),
        count: int,
        step_factor: wp.array(dtype=wp.vec2f),
        floor: wp.float32,
        free_powers: wp.array(dtype=Bins64),
        with_variance: int,
        bins: wp.array(dtype=Bins),
        mean: wp.array(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
        resets: wp.array(dtype=wp.int32),
    ):
        """One scan's groups of a pass sorted once (the parallel path), [first_group[scan],
        first_group[scan + 1]) of group_entry: each applies its voxel's factors of the scan in
        beam order (the sort is stable), then renormalises. Launched over the scan's steps, an
        upper bound the host knows (the group counts stay on the device)."""
        tid = wp.tid()
        if tid >= first_group[scan + 1] - first_group[scan]:
            return
        j = group_entry[first_group[scan] + tid]
        v = keys[j]
        free = int(0)
        while j < count:
            if keys[j] != v or step_scan[order[j]] != scan:
                break
            r = step_factor[order[j]]
            if passes_freely(r):
                if free == MOST_FREE_PASSES:  # counted passes applied before the next is counted
                    apply_free_passes(bins, v, free_powers, MOST_FREE_PASSES)
                    free = 0
                free += 1
            else:  # the passes counted so far go first: factors keep their order
                apply_free_passes(bins, v, free_powers, free)
                free = 0
                apply_factor(bins, v, r)
            j += 1
        finish_scan(bins, v, free_powers, free, floor, mean, variance, with_variance, resets)

    @wp.kernel(module=module)
    def variance_of_blocks(
        slots: wp.array(dtype=wp.int32),
        bins: wp.array(dtype=Bins),
        mean: wp.array(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
    ):
        """The variance of every observed voxel of the blocks in `slots` (the end of a batch)."""
        tid = wp.tid()
        slot = slots[tid // BLOCK_VOXELS]
        if slot < 0:
            return
        v = slot * BLOCK_VOXELS + tid % BLOCK_VOXELS
        if observed(mean[v]):
            variance[v] = moments(bins[v])[1]

    @wp.kernel(module=module)
    def compute_moments(
        observed: wp.array(dtype=wp.uint8),
        bins: wp.array(dtype=Bins),
        mean: wp.array(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
    ):
        """Mean and variance of observed voxels (a loaded map), NaN elsewhere."""
        tid = wp.tid()
        if observed[tid] == wp.uint8(0):
            mean[tid] = wp.nan
            variance[tid] = wp.nan
            return
        mv = moments(bins[tid])
        mean[tid] = mv[0]
        variance[tid] = mv[1]

    @wp.kernel(module=module)
    def lookup_bins(
        points: wp.array(dtype=wp.vec3f),
        inv_resolution: wp.float64,
        table_keys: wp.array(dtype=wp.int64),
        table_slots: wp.array(dtype=wp.int32),
        bins: wp.array(dtype=Bins),
        prior: Bins,
        values: wp.array(dtype=Bins),
    ):
        tid = wp.tid()
        voxel = voxel_key(points[tid], inv_resolution)
        slot = find_voxel_slot(table_keys, table_slots, voxel)
        if slot < 0:
            values[tid] = prior
        else:
            values[tid] = bins[slot * BLOCK_VOXELS + index_in_block(voxel)]

    return types.SimpleNamespace(
        Bins=Bins,
        Bins64=Bins64,
        free_powers=free_powers,
        integrate_in_order=integrate_in_order,
        variance_of_blocks=variance_of_blocks,
        apply_scan_groups=apply_scan_groups,
        compute_moments=compute_moments,
        lookup_bins=lookup_bins,
    )
