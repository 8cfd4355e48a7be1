"""ICP with the rotation held (free "translation", the sonar's closures) against a brute-force
NumPy reference of the same iteration: nearest neighbours from the full distance matrix, the
translation's 3 x 3 point-to-plane normal equations solved in their well-conditioned
eigen-directions, the same stopping rules (tolerance, starved, correspondences that come back).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vogjax import slam

from .test_slam import swath_pairs


def reference_translation_icp(source, prepared, T_init, config):
    """(T, converged, iterations): ICP holding T_init's rotation, written out plainly."""
    R, t = T_init[:3, :3], T_init[:3, 3].copy()
    target, normals = prepared.points, prepared.normals
    seen, iterations = {}, 0
    for iteration in range(1, config.max_iterations + 1):
        iterations = iteration
        moved = source @ R.T + t
        distance = np.linalg.norm(moved[:, None, :] - target[None, :, :], axis=2)
        nearest = distance.argmin(axis=1)
        inlier = distance[np.arange(len(moved)), nearest] < config.max_correspondence_m
        index = np.where(inlier, nearest, -1)
        plane = normals[nearest[inlier]]
        J = plane @ R
        residuals = np.sum(plane * (moved[inlier] - target[nearest[inlier]]), axis=1)
        values, vectors = np.linalg.eigh(J.T @ J)
        good = values >= config.lambda_min * max(inlier.sum(), 1)
        along = np.zeros(3)
        along[good] = (vectors[:, good].T @ (J.T @ residuals)) / values[good]
        step = R @ -(vectors @ along)
        t += step
        if inlier.sum() < config.min_inliers:
            return np.r_[np.c_[R, t], [[0, 0, 0, 1]]], False, iterations
        if np.linalg.norm(step) < config.tolerance:
            return np.r_[np.c_[R, t], [[0, 0, 0, 1]]], True, iterations
        if good.sum() < 3:
            seen.clear()
            continue
        key = index.tobytes()
        if key in seen and iteration - seen[key] >= 2:  # correspondences come back: a cycle
            return np.r_[np.c_[R, t], [[0, 0, 0, 1]]], False, iterations
        seen[key] = iteration
    return np.r_[np.c_[R, t], [[0, 0, 0, 1]]], False, iterations


@pytest.mark.parametrize("seed, overrides", [(0, {}), (3, {"tolerance": 1e-9}), (6, {"max_correspondence_m": 0.5})])
def test_held_rotation_matches_the_reference(seed, overrides):
    """Every pair of rough, flat and rotated swaths ends as the reference does: the same
    convergence and iterations, the translation to 1e-9 m, and the rotation T_init's bit for
    bit (it is held, not re-formed each step)."""
    sources, targets, starts = swath_pairs(seed, count=20)
    config = slam.IcpConfig(free="translation", **overrides)
    prepared = [slam.prepare_target(target, config) for target in targets]
    results = slam.icp_batch(sources, prepared, starts, config=config)
    stopped_early = 0
    for source, target, start, result in zip(sources, prepared, starts, results, strict=True):
        T, converged, iterations = reference_translation_icp(source, target, start, config)
        assert (result.converged, result.iterations) == (converged, iterations)
        assert np.array_equal(result.T_target_source[:3, :3], start[:3, :3])
        np.testing.assert_allclose(result.T_target_source[:3, 3], T[:3, 3], rtol=0, atol=1e-9)
        stopped_early += not converged and iterations < config.max_iterations
    assert stopped_early >= 1  # the cycle rule was exercised


@settings(max_examples=10, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    offset=st.tuples(*[st.floats(-0.2, 0.2)] * 3),
    rotvec=st.tuples(*[st.floats(-0.1, 0.1)] * 3),
)
def test_a_batch_ends_as_its_pairs_alone(seed, offset, rotvec):
    """A pair's result does not depend on the others in its batch (each stops on its own): the
    batch equals each pair aligned alone, bit for bit, and the reference to 1e-9 m."""
    sources, targets, _ = swath_pairs(seed % 1000, count=3)
    start = np.eye(4)
    start[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    start[:3, 3] = offset
    config = slam.IcpConfig(free="translation")
    batch = slam.icp_batch(sources, targets, [start] * 3, config=config)
    for source, target, result in zip(sources, targets, batch):
        alone = slam.icp(source, target, start, config=config)
        assert np.array_equal(alone.T_target_source, result.T_target_source)
        assert (alone.iterations, alone.converged) == (result.iterations, result.converged)
        T, converged, iterations = reference_translation_icp(source, slam.prepare_target(target), start, config)
        assert (result.converged, result.iterations) == (converged, iterations)
        np.testing.assert_allclose(result.T_target_source[:3, 3], T[:3, 3], rtol=0, atol=1e-9)
