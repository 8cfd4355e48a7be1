"""Exact voxel traversal (Amanatides-Woo) shared by integration and queries.

Two ways to start a walk:
- `segment_walk_begin` reproduces OctoMap's `computeRayKeys` operation for operation (float32
  beam geometry, float64 boundary distances, its tie-breaking), so integration touches exactly
  the voxels OctoMap does.
- `ray_walk_begin` starts from a float64 origin and unit direction, for planner ray casts.

Voxel k covers [k*s, (k+1)*s) on each axis.

Long rays: a ray walk's cost grows with its range, so ray casts skip the stretches where nothing
is known (before and after the map's box) in closed form: `ray_voxels_until` counts the voxels a
walk would visit up to a distance, `ray_walk_resume` restarts a walk at a voxel further on.
Both evaluate the boundary distances directly instead of summing steps, so they agree with a
step-by-step walk except where a voxel boundary lies within rounding of the distance.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

FAR = wp.constant(wp.float64(1.0e300))
# Voxels per axis a walk can meet inside the key range (hashing.VOXEL_KEY_LIMIT = 2^23 each way),
# so 3x this bounds the steps of any walk and the count stays far from int32's limit.
KEY_SPAN = wp.constant(wp.float64(1 << 24))
# A walk steps into a voxel the ray only touches at an edge or a corner whenever two planes that
# meet on the ray get distances a rounding apart (walk_step sums them plane by plane): a chord of
# about 1e-16 m. The confidence-rich map, where a voxel's bounce probability does not depend on
# its chord, counts a voxel only when the ray spends more than this many voxel edges in it. The
# summed distances err by far less: measured, 2e-9 edges over 10,000 voxels and 1.2e-7 over
# 65,536 (the longest query walk, blockmap.MAX_LINE_VOXELS).
MIN_CHORD_EDGES = wp.constant(wp.float64(1.0e-6))


@wp.struct
class VoxelWalk:
    """Where a walk starts and the per-axis constants it steps with.

    The moving state (current voxel, t_max, entry distance) lives in the caller's locals and is
    advanced by `walk_step`: copying a whole struct every step costs several times the step.
    """

    voxel: wp.vec3i  # first voxel
    last: wp.vec3i  # segment walks stop on reaching this voxel (it is not visited)
    step: wp.vec3i  # -1, 0 or +1 per axis
    t_max: wp.vec3d  # distance along the ray to the first voxel boundary, per axis
    t_delta: wp.vec3d  # distance between boundaries, per axis
    length: wp.float64  # segment length, or the range of a ray
    max_steps: int  # bound on the steps, against float round-off
    active: bool  # the first voxel is to be visited


@wp.func
def voxel_key(p: wp.vec3f, inv_resolution: wp.float64) -> wp.vec3i:
    # OctoMap: floor(coordinate * (1 / resolution)) in double precision.
    return wp.vec3i(
        int(wp.floor(wp.float64(p[0]) * inv_resolution)),
        int(wp.floor(wp.float64(p[1]) * inv_resolution)),
        int(wp.floor(wp.float64(p[2]) * inv_resolution)),
    )


@wp.func
def voxel_key_d(p: wp.vec3d, inv_resolution: wp.float64) -> wp.vec3i:
    return wp.vec3i(
        int(wp.floor(p[0] * inv_resolution)), int(wp.floor(p[1] * inv_resolution)), int(wp.floor(p[2] * inv_resolution))
    )


@wp.func
def norm_like_octomap(d: wp.vec3f) -> wp.float64:
    # float32 sum of squares, square root in double; separate statements so no FMA fuses them.
    xx = d[0] * d[0]
    yy = d[1] * d[1]
    zz = d[2] * d[2]
    s = xx + yy
    s = s + zz
    return wp.sqrt(wp.float64(s))


@wp.func
def same_voxel(a: wp.vec3i, b: wp.vec3i) -> bool:
    return a[0] == b[0] and a[1] == b[1] and a[2] == b[2]


@wp.func
def l1_distance(a: wp.vec3i, b: wp.vec3i) -> int:
    return wp.abs(a[0] - b[0]) + wp.abs(a[1] - b[1]) + wp.abs(a[2] - b[2])


@wp.func
def segment_walk_begin(
    origin: wp.vec3f, end: wp.vec3f, resolution: wp.float64, inv_resolution: wp.float64
) -> VoxelWalk:
    w = VoxelWalk()
    w.voxel = voxel_key(origin, inv_resolution)
    w.last = voxel_key(end, inv_resolution)
    d = wp.vec3f(end[0] - origin[0], end[1] - origin[1], end[2] - origin[2])
    length = wp.float32(norm_like_octomap(d))
    w.length = wp.float64(length)
    w.step = wp.vec3i(0, 0, 0)
    w.t_max = wp.vec3d(FAR, FAR, FAR)
    w.t_delta = wp.vec3d(FAR, FAR, FAR)
    half = wp.float64(0.5)
    for i in range(3):
        direction = d[i] / length
        if direction > wp.float32(0.0):
            w.step[i] = 1
        elif direction < wp.float32(0.0):
            w.step[i] = -1
        if w.step[i] != 0:
            border = (wp.float64(w.voxel[i]) + half) * resolution
            border = border + wp.float64(wp.float32(wp.float64(w.step[i]) * resolution * half))
            w.t_max[i] = (border - wp.float64(origin[i])) / wp.float64(direction)
            w.t_delta[i] = resolution / wp.abs(wp.float64(direction))
    w.max_steps = l1_distance(w.voxel, w.last) + 2
    # A segment whose float32 length underflows to 0 (under about 3e-23 m, across a plane
    # through 0) has no direction: walked, its infinite t's would step l1 + 2 voxels along
    # one axis (OctoMap loops forever on it). It walks nothing, like a segment within a voxel.
    w.active = not same_voxel(w.voxel, w.last) and length > wp.float32(0.0)
    return w


@wp.func
def ray_walk_begin(
    origin: wp.vec3d, direction: wp.vec3d, resolution: wp.float64, inv_resolution: wp.float64, max_range: wp.float64
) -> VoxelWalk:
    # Branch-free: a direction's signs are random from ray to ray, so a branch on each
    # mispredicts about half the time (a few of them cost more than the rest of the set-up).
    # Each axis computes both sides and selects one: the same operations, the same bits.
    w = VoxelWalk()
    voxel = voxel_key_d(origin, inv_resolution)
    w.voxel = voxel
    w.last = voxel
    w.length = max_range
    step = wp.vec3i(0, 0, 0)
    t_max = wp.vec3d(FAR, FAR, FAR)
    t_delta = wp.vec3d(FAR, FAR, FAR)
    for i in range(3):
        up = direction[i] > wp.float64(0.0)
        moves = direction[i] != wp.float64(0.0)
        step[i] = wp.where(up, 1, wp.where(moves, -1, 0))
        face = wp.float64(voxel[i] + wp.where(up, 1, 0)) * resolution  # the far face: above, or below
        t_max[i] = wp.where(moves, (face - origin[i]) / direction[i], FAR)
        t_delta[i] = wp.where(moves, resolution / wp.abs(direction[i]), FAR)
    w.step = step
    w.t_max = t_max
    w.t_delta = t_delta
    # in float64 and capped: 3 * int(range / s) overflows int32 for ranges above ~7e7 voxels
    w.max_steps = 3 * int(wp.min(max_range * inv_resolution, KEY_SPAN)) + 6
    w.active = max_range > wp.float64(0.0)
    return w


@wp.func
def unit_direction(d: wp.vec3d) -> wp.vec3d:
    """A nonzero finite direction scaled to unit length; one whose squared length would
    overflow or underflow is first divided by its largest |component| (blockmap.unit_directions
    on the host)."""
    squared = wp.dot(d, d)
    if not (squared > wp.float64(1e-300) and squared < wp.float64(1e300)):
        d = d / wp.max(wp.max(wp.abs(d[0]), wp.abs(d[1])), wp.abs(d[2]))
        squared = wp.dot(d, d)
    return d / wp.sqrt(squared)


@wp.func
def ray_walk_resume(
    origin: wp.vec3d, direction: wp.vec3d, voxel: wp.vec3i, step: wp.vec3i, resolution: wp.float64
) -> wp.vec3d:
    """t_max of a ray walk (from `origin` along unit `direction`) that has reached `voxel`:
    the distance to the voxel's far boundary per axis, as ray_walk_begin computes it."""
    t_max = wp.vec3d(FAR, FAR, FAR)
    for i in range(3):
        if step[i] > 0:
            t_max[i] = (wp.float64(voxel[i] + 1) * resolution - origin[i]) / direction[i]
        elif step[i] < 0:
            t_max[i] = (wp.float64(voxel[i]) * resolution - origin[i]) / direction[i]
    return t_max


@wp.func
def ray_voxel_at(
    origin: wp.vec3d, direction: wp.vec3d, voxel: wp.vec3i, step: wp.vec3i, inv_resolution: wp.float64, t: wp.float64
) -> wp.vec3i:
    """The voxel holding the ray's point at distance t, for a walk now in `voxel` (a walk is
    monotone per axis, so round-off never puts it behind that voxel)."""
    v = voxel_key_d(origin + direction * t, inv_resolution)
    for i in range(3):
        if (v[i] - voxel[i]) * step[i] <= 0:
            v[i] = voxel[i]
    return v


@wp.func
def ray_entry(
    origin: wp.vec3d, direction: wp.vec3d, voxel: wp.vec3i, target: wp.vec3i, step: wp.vec3i, resolution: wp.float64
) -> wp.float64:
    """Distance at which a walk now in `voxel` enters `target` further on: the latest of the
    entry faces of `target` on the axes it moves along (-FAR when target is voxel)."""
    t = -FAR
    for i in range(3):
        if target[i] != voxel[i]:
            face = wp.float64(target[i]) + wp.where(step[i] < 0, wp.float64(1.0), wp.float64(0.0))
            t = wp.max(t, (face * resolution - origin[i]) / direction[i])
    return t


@wp.func
def ray_voxels_until(
    origin: wp.vec3d,
    direction: wp.vec3d,
    voxel: wp.vec3i,
    step: wp.vec3i,
    resolution: wp.float64,
    inv_resolution: wp.float64,
    t_end: wp.float64,
) -> int:
    """Voxels a ray walk now in `voxel` visits from it on, it included, entering each before
    t_end. Each step moves one axis by one, so that is the L1 distance to the voxel holding the
    point at t_end, plus one, less that voxel if the walk enters it at t_end or later."""
    last = ray_voxel_at(origin, direction, voxel, step, inv_resolution, t_end)
    n = l1_distance(voxel, last) + 1
    if n > 1 and ray_entry(origin, direction, voxel, last, step, resolution) >= t_end:
        n -= 1
    return n


@wp.func
def ray_key_range(origin: wp.vec3d, direction: wp.vec3d, resolution: wp.float64, limit: int) -> wp.float64:
    """Distance at which the ray leaves the key range [-limit, limit) voxels per axis."""
    bound = wp.float64(limit) * resolution  # float64(-limit) * resolution is exactly -bound
    t = FAR
    for i in range(3):  # branch-free, as in ray_walk_begin
        face = wp.where(direction[i] > wp.float64(0.0), bound, -bound)
        t = wp.where(direction[i] != wp.float64(0.0), wp.min(t, (face - origin[i]) / direction[i]), t)
    return t


@wp.func
def ray_box_span(origin: wp.vec3d, direction: wp.vec3d, lo: wp.vec3d, hi: wp.vec3d) -> wp.vec2d:
    """[t_in, t_out] of the ray (all t, negative included) inside the box [lo, hi]; empty
    (t_in > t_out) when it misses."""
    t_in = -FAR
    t_out = FAR
    for i in range(3):  # branch-free, as in ray_walk_begin
        a = (lo[i] - origin[i]) / direction[i]
        b = (hi[i] - origin[i]) / direction[i]
        # parallel to the slab: every t inside it, none outside
        inside = origin[i] >= lo[i] and origin[i] <= hi[i]
        moves = direction[i] != wp.float64(0.0)
        t_in = wp.where(moves, wp.max(t_in, wp.min(a, b)), wp.where(inside, t_in, FAR))
        t_out = wp.where(moves, wp.min(t_out, wp.max(a, b)), wp.where(inside, t_out, -FAR))
    return wp.vec2d(t_in, t_out)


@wp.func
def entered_new_block(coordinate: int, step: int) -> bool:
    # Stepping up enters a block at local coordinate 0, stepping down at 7 ((-1 >> 1) & 7).
    return (coordinate & 7) == ((step >> 1) & 7)


@wp.func
def walk_step(voxel: wp.vec3i, step: wp.vec3i, t_max: wp.vec3d, t_delta: wp.vec3d):
    """Next voxel, its t_max, the distance at which the walk enters it, and whether that voxel
    lies in another 8x8x8 block than the last one (so callers look blocks up only then).

    OctoMap's tie-breaking: strict comparisons, so z wins three-way ties and y beats z.
    """
    if t_max[0] < t_max[1] and t_max[0] < t_max[2]:
        x = voxel[0] + step[0]
        return (
            wp.vec3i(x, voxel[1], voxel[2]),
            wp.vec3d(t_max[0] + t_delta[0], t_max[1], t_max[2]),
            t_max[0],
            entered_new_block(x, step[0]),
        )
    if t_max[1] < t_max[2] and not t_max[0] < t_max[1]:
        y = voxel[1] + step[1]
        return (
            wp.vec3i(voxel[0], y, voxel[2]),
            wp.vec3d(t_max[0], t_max[1] + t_delta[1], t_max[2]),
            t_max[1],
            entered_new_block(y, step[1]),
        )
    z = voxel[2] + step[2]
    return (
        wp.vec3i(voxel[0], voxel[1], z),
        wp.vec3d(t_max[0], t_max[1], t_max[2] + t_delta[2]),
        t_max[2],
        entered_new_block(z, step[2]),
    )


@wp.func
def smaller(a: wp.float64, b: wp.float64) -> wp.float64:
    """wp.min of two distances, which are never NaN: one select (wp.min also tests for NaN,
    which keeps a walk's step from compiling to plain compares)."""
    return wp.where(a <= b, a, b)


@wp.func
def first_boundary(t_max: wp.vec3d, length: wp.float64) -> wp.float64:
    """Where a walk leaves its voxel: the nearest boundary, or `length` if that comes first."""
    return smaller(smaller(smaller(t_max[0], t_max[1]), t_max[2]), length)


@wp.func
def holds_chord(t_in: wp.float64, t_out: wp.float64, resolution: wp.float64) -> bool:
    """Whether a ray spends more than MIN_CHORD_EDGES voxel edges between t_in and t_out."""
    return t_out - t_in > MIN_CHORD_EDGES * resolution


@wp.func
def segment_continues(voxel: wp.vec3i, t_max: wp.vec3d, w: VoxelWalk, steps: int) -> bool:
    # OctoMap stops on reaching the end voxel, or when round-off carried it past the end.
    return (
        not same_voxel(voxel, w.last)
        and wp.min(wp.min(t_max[0], t_max[1]), t_max[2]) <= w.length
        and steps <= w.max_steps
    )
