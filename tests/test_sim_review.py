"""From a review of the simulator, sensors and confidence map: a scan without a random source is
noise-free and repeatable, a beam of an even number of sub-rays is recorded along its axis, a
one-beam fan points along its tilt and a full circle repeats no beam, noise takes no return past
the reach, and a range sigma too small for the cone is refused. Each case failed on the code
before it."""

import numpy as np
import pytest
import trimesh

import vogjax as vj
from vogjax.sensors import as_sensor
from vogjax.sim import scan

from .test_sim import warp_mesh


def looking_at_a_box(count=6):
    poses = np.tile(np.eye(4), (count, 1, 1))
    poses[:, 0, 3] = -5.0 + 0.1 * np.arange(count)
    return warp_mesh(trimesh.creation.box(extents=[2.0, 6.0, 6.0])), poses


def test_a_scan_without_a_random_source_is_noise_free_and_repeatable():
    mesh, poses = looking_at_a_box()
    noisy = vj.SonarConfig(min_range_m=0.0, max_range_m=20.0, range_noise_m=0.05)
    exact = vj.SonarConfig(min_range_m=0.0, max_range_m=20.0, range_noise_m=0.0)
    first, second, reference = scan(mesh, poses, noisy), scan(mesh, poses, noisy), scan(mesh, poses, exact)
    assert np.array_equal(first.ranges, second.ranges, equal_nan=True)
    assert np.array_equal(first.ranges, reference.ranges, equal_nan=True)
    seeded = scan(mesh, poses, noisy, np.random.default_rng(3))  # a source given: its noise
    hit = ~np.isnan(reference.ranges)
    assert hit.any() and 0.02 < np.std(seeded.ranges[hit] - reference.ranges[hit]) < 0.08


@pytest.mark.parametrize("subrays", [2, 4])
def test_a_beam_of_an_even_number_of_sub_rays_is_recorded_along_its_axis(subrays):
    """The middle index of two sub-rays is an edge ray: the beam was recorded half its aperture
    (5 degrees) across the fan, and every endpoint placed off the surface."""
    even = as_sensor(vj.SonarConfig(subrays=subrays, aperture_deg=10.0))
    odd = as_sensor(vj.SonarConfig(subrays=3, aperture_deg=10.0))
    np.testing.assert_allclose(even.beam_axes(), odd.beam_axes(), atol=1e-12)
    assert np.array_equal(odd.beam_axes(), odd.beam_directions()[:, 1])  # odd: the central ray, bit for bit
    fields = even.dataset_fields(np.ones((1, even.config.beams)), np.zeros((1, even.config.beams), bool))
    np.testing.assert_allclose(
        fields["sonar_directions"][0], odd.beam_axes() @ odd.T_vehicle_sensor[:3, :3].T, atol=1e-12
    )
    mesh, poses = looking_at_a_box()
    recorded = scan(mesh, poses, even.config).directions
    np.testing.assert_allclose(recorded[0], odd.beam_axes() @ poses[0, :3, :3].T, atol=1e-6)


def test_a_one_beam_fan_points_along_its_tilt_and_a_circle_repeats_no_beam():
    one = as_sensor(vj.SonarConfig(beams=1, fov_deg=29.0, tilt_deg=-10.0)).beam_axes()[0]
    np.testing.assert_allclose(one, [np.cos(np.radians(-10.0)), 0.0, np.sin(np.radians(-10.0))], atol=1e-15)
    circle = as_sensor(vj.SonarConfig(beams=8, fov_deg=360.0, tilt_deg=0.0)).beam_axes()
    elevations = np.degrees(np.arctan2(circle[:, 2], circle[:, 0]))
    assert len(np.unique(np.round(elevations, 9))) == 8
    np.testing.assert_allclose(np.diff(np.unwrap(np.radians(elevations))), np.radians(45.0), atol=1e-12)
    fan = as_sensor(vj.SonarConfig(beams=5, fov_deg=40.0, tilt_deg=0.0)).beam_axes()  # as before: both ends
    np.testing.assert_allclose(np.degrees(np.arctan2(fan[:, 2], fan[:, 0])), [-20, -10, 0, 10, 20], atol=1e-12)


def test_noise_never_takes_a_return_past_the_sensors_reach():
    """A wall just inside the reach, 5 cm of noise: returns the noise took past max_range_m
    were kept, above the longest return the sensor is documented to give."""
    mesh, poses = looking_at_a_box()
    reach = 4.05  # the box's face is 4.0-4.5 m ahead of these poses
    config = vj.SonarConfig(min_range_m=0.0, max_range_m=reach, range_noise_m=0.05)
    exact = scan(mesh, poses, config.replace(range_noise_m=0.0))
    noisy = scan(mesh, poses, config, np.random.default_rng(0))
    returned = ~noisy.no_return & ~noisy.invalid
    assert returned.any() and np.nanmax(noisy.ranges) <= reach
    assert (~exact.no_return & noisy.no_return).any()  # what the noise took past the reach
    assert np.all(np.isnan(noisy.ranges[noisy.no_return]))


@pytest.mark.parametrize("sigma", [1e-7, 1e-17, 1e-300])
def test_a_range_sigma_too_small_to_walk_a_cone_is_refused(sigma):
    """Below a range's rounding the cone collapsed onto the reading: its voxel explained nothing
    and stayed at the prior, marked observed, where a micrometre and above are exact."""
    with pytest.raises(ValueError, match="range_sigma_m"):
        vj.CrmConfig(range_sigma_m=sigma)
    crm = vj.ConfidenceMap(vj.CrmConfig(range_sigma_m=1e-6), device="cpu")
    origin, end = np.array([0.05, 0.05, 0.05]), np.array([2.05, 0.05, 0.05])
    for _ in range(5):
        crm.integrate_scan(origin, end[None])
    assert crm.mean(end[None])[0] > 0.8
