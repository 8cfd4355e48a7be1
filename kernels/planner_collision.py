"""Collision checks of planner edges: a box swept along a segment against the map.

A voxel is in the swept box when its cube meets the box at some point of the segment, i.e. when
the segment meets the voxel's cube grown by the box's half extents (closed intervals: touching
counts). Threads run over (edge, voxel column in x-y); a column walks z through the edge's
bounding box. Voxels that meet the box at the vehicle's position are free (it is there).
OCCUPIED voxels are unsafe. UNKNOWN ones are unsafe unless their centre lies within the
clearance radius of the vehicle's position (with `layer_only`, and meets the height of the
vehicle's own box: the water above and below it was never seen, so no climb or descent enters
it on the clearance's word) or (on an edge
that moves in x-y; with `layer_only`, on any edge that moves) the voxel of their column at the
height of the edge's centre line there is FREE (with `layer_only`, or lies in the vehicle's
box, which is water): a sonar fan sees along the layer it travels in, and the box's thin top
and bottom slabs take that layer's state; a climb straight up enters only layers seen free.
"""

import warp as wp

from .hashing import block_of
from .planner_maps import FREE, OCCUPIED, UNKNOWN, MapAccess, state_of, store_slot, voxel_value
from .submap_view import voxel_centre

wp.set_module_options({"enable_backward": False})


@wp.func
def segment_meets_box(start: wp.vec3d, end: wp.vec3d, lo: wp.vec3d, hi: wp.vec3d) -> bool:
    """Does the segment start->end meet the closed box [lo, hi]? (slab test)"""
    t0 = wp.float64(0.0)
    t1 = wp.float64(1.0)
    for axis in range(3):
        d = end[axis] - start[axis]
        if d == wp.float64(0.0):
            if start[axis] < lo[axis] or start[axis] > hi[axis]:
                return False
        else:
            a = (lo[axis] - start[axis]) / d
            b = (hi[axis] - start[axis]) / d
            t0 = wp.max(t0, wp.min(a, b))
            t1 = wp.min(t1, wp.max(a, b))
    return t0 <= t1


@wp.func
def boxes_meet(lo_a: wp.vec3d, hi_a: wp.vec3d, lo_b: wp.vec3d, hi_b: wp.vec3d) -> bool:
    return (
        lo_a[0] <= hi_b[0]
        and lo_b[0] <= hi_a[0]
        and lo_a[1] <= hi_b[1]
        and lo_b[1] <= hi_a[1]
        and lo_a[2] <= hi_b[2]
        and lo_b[2] <= hi_a[2]
    )


@wp.func
def centre_layer_free(
    m: MapAccess,
    start: wp.vec3d,
    end: wp.vec3d,
    voxel: wp.vec3i,
    centre: wp.vec3d,
    candidates: wp.array(dtype=wp.int32),
    first: int,
    last: int,
    vehicle_lo: wp.vec3d,
    vehicle_hi: wp.vec3d,
    seen_layers: int,
) -> bool:
    """Is the voxel of `voxel`'s column at the height of the edge's centre line FREE? The
    height is the line's where it passes nearest the voxel's centre in x-y; none for an edge
    without x-y motion, nor when that voxel is `voxel` itself. With seen_layers, also: an edge
    straight up or down takes the line's height nearest the voxel's (the layer at the top of a
    climb for the slab above it: a climb may enter only layers seen free), and on an edge that
    moves in x-y a layer voxel in the vehicle's box is water (the vehicle is there)."""
    dx = end[0] - start[0]
    dy = end[1] - start[1]
    dz = end[2] - start[2]
    flat = dx * dx + dy * dy
    t = wp.float64(0.0)
    if flat == wp.float64(0.0):
        if seen_layers == 0 or dz == wp.float64(0.0):
            return False
        t = wp.clamp((centre[2] - start[2]) / dz, wp.float64(0.0), wp.float64(1.0))
    else:
        t = wp.clamp(
            ((centre[0] - start[0]) * dx + (centre[1] - start[1]) * dy) / flat, wp.float64(0.0), wp.float64(1.0)
        )
    layer = wp.vec3i(voxel[0], voxel[1], int(wp.floor((start[2] + t * dz) * m.inv_resolution)))
    if layer[2] == voxel[2]:
        return False
    if seen_layers != 0 and flat > wp.float64(0.0):  # a climb's layers must be seen, not assumed
        s = m.resolution
        lo = wp.vec3d(wp.float64(layer[0]) * s, wp.float64(layer[1]) * s, wp.float64(layer[2]) * s)
        if boxes_meet(lo, lo + wp.vec3d(s, s, s), vehicle_lo, vehicle_hi):
            return True
    value = voxel_value(m, layer, store_slot(m, layer), candidates, first, last)
    return state_of(m, value) == FREE


@wp.kernel
def count_unsafe_voxels(
    first_edge: int,
    starts: wp.array(dtype=wp.vec3d),
    ends: wp.array(dtype=wp.vec3d),
    half: wp.vec3d,
    half_obstacle: wp.vec3d,
    first_voxels: wp.array(dtype=wp.vec3i),
    sizes: wp.array(dtype=wp.vec3i),
    m: MapAccess,
    candidate_offsets: wp.array(dtype=wp.int32),
    candidates: wp.array(dtype=wp.int32),
    vehicle: wp.vec3d,
    clearance: wp.float64,
    layer_only: int,
    unsafe: wp.array(dtype=wp.int32),
):
    """unsafe[edge] > 0 when the box swept along the edge holds an unsafe voxel, or the larger
    box of half extents half_obstacle (>= half) holds an OCCUPIED one that it does not already
    hold at the vehicle's position (known obstacles are kept farther off, as the vehicle's
    estimate drifts from where they were mapped; an edge may still leave a wall it is near).
    sizes[edge]: voxels per axis of the edge's bounding box (grown by half_obstacle), from
    first_voxels[edge]."""
    e, column = wp.tid()
    e = e + first_edge
    size = sizes[e]
    if column >= size[0] * size[1]:
        return
    if unsafe[e] > 0:
        # already blocked: only unsafe[e] == 0 is read, so the edge's other columns need no look
        # (a CPU runs the threads in order and skips them all; on a GPU a racing thread may not)
        return
    start = starts[e]
    end = ends[e]
    s = m.resolution
    vehicle_lo = vehicle - half
    vehicle_hi = vehicle + half
    first = candidate_offsets[e]
    last = candidate_offsets[e + 1]
    # columns from the edge's end first: the start lies in water the vehicle has seen, so a
    # blocked edge is found blocked sooner, and the early return above skips more
    ix = column / size[1]
    iy = column % size[1]
    if end[0] >= start[0]:
        ix = size[0] - 1 - ix
    if end[1] >= start[1]:
        iy = size[1] - 1 - iy
    voxel = wp.vec3i(first_voxels[e][0] + ix, first_voxels[e][1] + iy, first_voxels[e][2])
    slot = int(-1)
    block = wp.vec3i(0, 0, 0)
    looked_up = bool(False)
    for k in range(size[2]):
        voxel = wp.vec3i(voxel[0], voxel[1], first_voxels[e][2] + k)
        lo = wp.vec3d(wp.float64(voxel[0]) * s, wp.float64(voxel[1]) * s, wp.float64(voxel[2]) * s)
        hi = wp.vec3d(lo[0] + s, lo[1] + s, lo[2] + s)
        if not segment_meets_box(start, end, lo - half_obstacle, hi + half_obstacle):
            continue
        in_box = segment_meets_box(start, end, lo - half, hi + half)
        if in_box and boxes_meet(lo, hi, vehicle_lo, vehicle_hi):
            continue  # where the vehicle is: water, whatever the map says
        here = block_of(voxel)
        if not looked_up or here[2] != block[2]:
            slot = store_slot(m, voxel)
            block = here
            looked_up = True
        state = state_of(m, voxel_value(m, voxel, slot, candidates, first, last))
        if state == OCCUPIED:
            if in_box or not boxes_meet(lo, hi, vehicle - half_obstacle, vehicle + half_obstacle):
                wp.atomic_add(unsafe, e, 1)
                return
            continue
        if state == UNKNOWN and in_box:
            centre = voxel_centre(voxel, s)
            near = wp.length(centre - vehicle) <= clearance
            if near and layer_only != 0:  # its cube meets the height of the vehicle's box
                near = wp.abs(centre[2] - vehicle[2]) <= half[2] + wp.float64(0.5) * s
            if not (
                near
                or centre_layer_free(
                    m, start, end, voxel, centre, candidates, first, last, vehicle_lo, vehicle_hi, layer_only
                )
            ):
                wp.atomic_add(unsafe, e, 1)
                return
