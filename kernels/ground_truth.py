"""Ground truth of the built-in scenes: which voxel centres lie inside a closed mesh."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def flag_points_inside(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), inside: wp.array(dtype=wp.int32)):
    """inside[i] = 1 where the generalised winding number puts points[i] inside the mesh."""
    tid = wp.tid()
    # Built-in solids are at most a couple of metres thick: farther from a surface is water.
    query = wp.mesh_query_point_sign_winding_number(mesh, points[tid], 1.5, 2.0, 0.5)
    inside[tid] = wp.where(query.result and query.sign < 0.0, 1, 0)
