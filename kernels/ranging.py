"""Simulated range-sensor returns by ray casting against a scene mesh."""

import warp as wp

wp.set_module_options({"enable_backward": False})

NO_RETURN = wp.constant(-1.0)
# the beam's surface lies within the blind distance: the echo is lost, the beam is invalid
INVALID = wp.constant(-2.0)


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
    NO_RETURN where none lies within max_range; INVALID where a sub-ray meets the surface
    within min_range (the sensor's blind distance hides that surface, so the beam says nothing
    about the water along it) or meets a face from behind (the sensor is inside a solid: a
    survey that runs the bow into an obstacle)."""
    scan, beam = wp.tid()
    origin = origins[scan]
    nearest = float(NO_RETURN)
    blind = bool(False)
    for sub in range(beam_directions.shape[1]):
        direction = rotations[scan] * beam_directions[beam, sub]
        query = wp.mesh_query_ray(mesh, origin, direction, max_range)
        if query.result:
            if query.t < min_range or query.sign < 0.0:
                blind = True
            elif nearest < 0.0 or query.t < nearest:
                nearest = query.t
    if blind:
        nearest = INVALID
    ranges[scan, beam] = nearest
