"""Simulated range-sensor returns by ray casting against a scene mesh."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def cast_sensor_beams(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.mat33),
    beam_directions: wp.array2d(dtype=wp.vec3),
    min_range: float,
    max_range: float,
    ranges: wp.array2d(dtype=float),
):
    """ranges[scan, beam]: nearest return over the beam's sub-rays (its elevation aperture);
    -1 where none lies within [min_range, max_range]."""
    scan, beam = wp.tid()
    origin = origins[scan]
    nearest = float(-1.0)
    for sub in range(beam_directions.shape[1]):
        direction = rotations[scan] * beam_directions[beam, sub]
        query = wp.mesh_query_ray(mesh, origin, direction, max_range)
        if query.result and query.t >= min_range:
            if nearest < 0.0 or query.t < nearest:
                nearest = query.t
    ranges[scan, beam] = nearest
