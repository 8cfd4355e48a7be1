"""Exact voxel traversal (Amanatides-Woo) shared by integration and queries.

Two ways to start a walk:
- `segment_walk_begin` reproduces OctoMap's `computeRayKeys` operation for operation (float32
  beam geometry, float64 boundary distances, its tie-breaking), so integration touches exactly
  the voxels OctoMap does.
- `ray_walk_begin` starts from a float64 origin and unit direction, for planner ray casts.

Voxel k covers [k*s, (k+1)*s) on each axis.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

FAR = wp.constant(wp.float64(1.0e300))


@wp.struct
class VoxelWalk:
    voxel: wp.vec3i  # the voxel the walk is in
    last: wp.vec3i  # segment walks stop on reaching this voxel (it is not visited)
    step: wp.vec3i  # -1, 0 or +1 per axis
    t_max: wp.vec3d  # distance along the ray to the next voxel boundary, per axis
    t_delta: wp.vec3d  # distance between boundaries, per axis
    t_entry: wp.float64  # distance at which the walk entered `voxel`
    length: wp.float64  # segment length
    steps_left: int  # bound on the remaining steps, against float round-off
    active: bool  # the walk is in a voxel it should visit


@wp.func
def voxel_key(p: wp.vec3f, inv_resolution: wp.float64) -> wp.vec3i:
    # OctoMap: floor(coordinate * (1 / resolution)) in double precision.
    return wp.vec3i(int(wp.floor(wp.float64(p[0]) * inv_resolution)),
                    int(wp.floor(wp.float64(p[1]) * inv_resolution)),
                    int(wp.floor(wp.float64(p[2]) * inv_resolution)))


@wp.func
def voxel_key_d(p: wp.vec3d, inv_resolution: wp.float64) -> wp.vec3i:
    return wp.vec3i(int(wp.floor(p[0] * inv_resolution)),
                    int(wp.floor(p[1] * inv_resolution)),
                    int(wp.floor(p[2] * inv_resolution)))


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
def segment_walk_begin(origin: wp.vec3f, end: wp.vec3f, resolution: wp.float64,
                       inv_resolution: wp.float64) -> VoxelWalk:
    w = VoxelWalk()
    w.voxel = voxel_key(origin, inv_resolution)
    w.last = voxel_key(end, inv_resolution)
    d = wp.vec3f(end[0] - origin[0], end[1] - origin[1], end[2] - origin[2])
    length = wp.float32(norm_like_octomap(d))
    w.length = wp.float64(length)
    w.t_entry = wp.float64(0.0)
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
    w.steps_left = l1_distance(w.voxel, w.last) + 2
    w.active = not same_voxel(w.voxel, w.last)
    return w


@wp.func
def ray_walk_begin(origin: wp.vec3d, direction: wp.vec3d, resolution: wp.float64,
                   inv_resolution: wp.float64, max_range: wp.float64) -> VoxelWalk:
    w = VoxelWalk()
    w.voxel = voxel_key_d(origin, inv_resolution)
    w.last = w.voxel
    w.length = max_range
    w.t_entry = wp.float64(0.0)
    w.step = wp.vec3i(0, 0, 0)
    w.t_max = wp.vec3d(FAR, FAR, FAR)
    w.t_delta = wp.vec3d(FAR, FAR, FAR)
    for i in range(3):
        if direction[i] > wp.float64(0.0):
            w.step[i] = 1
            w.t_max[i] = (wp.float64(w.voxel[i] + 1) * resolution - origin[i]) / direction[i]
        elif direction[i] < wp.float64(0.0):
            w.step[i] = -1
            w.t_max[i] = (wp.float64(w.voxel[i]) * resolution - origin[i]) / direction[i]
        if w.step[i] != 0:
            w.t_delta[i] = resolution / wp.abs(direction[i])
    w.steps_left = 3 * int(max_range * inv_resolution) + 6
    w.active = max_range > wp.float64(0.0)
    return w


@wp.func
def walk_step(w: VoxelWalk) -> VoxelWalk:
    """Move to the next voxel (OctoMap's tie-breaking: strict comparisons, z wins ties)."""
    dim = int(2)
    if w.t_max[0] < w.t_max[1]:
        if w.t_max[0] < w.t_max[2]:
            dim = 0
    elif w.t_max[1] < w.t_max[2]:
        dim = 1
    r = w
    r.t_entry = w.t_max[dim]
    r.voxel[dim] = w.voxel[dim] + w.step[dim]
    r.t_max[dim] = w.t_max[dim] + w.t_delta[dim]
    r.steps_left = w.steps_left - 1
    return r


@wp.func
def segment_walk_next(w: VoxelWalk) -> VoxelWalk:
    r = walk_step(w)
    if same_voxel(r.voxel, r.last):
        r.active = False
    elif wp.min(wp.min(r.t_max[0], r.t_max[1]), r.t_max[2]) > r.length:
        # OctoMap's guard: round-off carried the walk past the end voxel.
        r.active = False
    if r.steps_left < 0:
        r.active = False
    return r


@wp.func
def ray_walk_next(w: VoxelWalk) -> VoxelWalk:
    r = walk_step(w)
    r.active = r.t_entry < r.length and r.steps_left >= 0
    return r
