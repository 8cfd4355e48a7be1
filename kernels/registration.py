"""The SLAM front end's inner loops on the device: the correlative search's scores by direct
correlation, and ICP's nearest-neighbour correspondences from a hash grid.

Both give what the host path (`vogjax.slam.correlative`, `vogjax.slam.icp`) gives: every score
is a sum in a fixed order (float64, so it differs from the host's FFT only in rounding), and
every nearest neighbour is the closest point strictly within the bound, ties going to the lowest
index, as the k-d tree finds it.
"""

import warp as wp

# No fused multiply-adds: a squared distance must round as NumPy's and the k-d tree's do, or a
# near tie could go the other way on a GPU (Warp fuses by default there, not on the CPU).
wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.kernel
def correlate_shifted_cells(
    field: wp.array(dtype=wp.float32),
    search_field_start: wp.array(dtype=wp.int32),
    search_dims: wp.array(dtype=wp.vec3i),
    search_shift: wp.array(dtype=wp.int32),
    slot_search: wp.array(dtype=wp.int32),
    slot_cell_start: wp.array(dtype=wp.int32),
    slot_cell_count: wp.array(dtype=wp.int32),
    slot_window_start: wp.array(dtype=wp.int32),
    cells: wp.array(dtype=wp.vec3i),
    windows: wp.array(dtype=wp.float64),
):
    """One thread per score: windows[slot](i, j) = sum over the slot's cells c of
    field[c + (i - shift, j - shift, 0)]. A slot is one (search, yaw), its window (2 shift + 1)^2
    scores from slot_window_start[slot] (one more entry: the total); its field is the search's
    blurred target, (nx, ny, nz) in C order from search_field_start; cells beyond the field add
    nothing (the host's margins keep every real overlap inside it)."""
    tid = wp.tid()
    # the slot whose window holds this score: the last one starting at or before it
    slot = int(0)
    end = slot_window_start.shape[0] - 1
    while end - slot > 1:
        middle = (slot + end) // 2
        if slot_window_start[middle] <= tid:
            slot = middle
        else:
            end = middle
    search = slot_search[slot]
    shift = search_shift[search]
    width = 2 * shift + 1
    local = tid - slot_window_start[slot]
    i = local // width
    j = local - i * width
    dims = search_dims[search]
    start = search_field_start[search]
    dx = i - shift
    dy = j - shift
    total = wp.float64(0.0)
    first = slot_cell_start[slot]
    for k in range(first, first + slot_cell_count[slot]):
        c = cells[k]
        x = c[0] + dx
        y = c[1] + dy
        if x >= 0 and x < dims[0] and y >= 0 and y < dims[1] and c[2] >= 0 and c[2] < dims[2]:
            total += wp.float64(field[start + (x * dims[1] + y) * dims[2] + c[2]])
    windows[tid] = total


@wp.kernel
def find_nearest_points(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    queries: wp.array(dtype=wp.vec3d),
    query_group: wp.array(dtype=wp.int32),
    max_distance: wp.float64,
    nearest: wp.array(dtype=wp.int32),
):
    """nearest[q]: the index of the point of group query_group[q] closest to queries[q] and
    strictly within max_distance (ties: the lowest index); -1 when there is none."""
    tid = wp.tid()
    p = queries[tid]
    best = int(-1)
    best_d2 = max_distance * max_distance
    # a hair wider than the bound: the cells a query visits come from rounded coordinates
    query = wp.hash_grid_query(grid, p, max_distance * wp.float64(1.000001), query_group[tid])
    index = int(0)
    while wp.hash_grid_query_next(query, index):
        d = points[index] - p
        d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        if d2 < best_d2 or (d2 == best_d2 and best >= 0 and index < best):
            best = index
            best_d2 = d2
    nearest[tid] = best
