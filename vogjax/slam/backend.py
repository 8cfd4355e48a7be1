"""The pose graph over submap base poses, on GTSAM's iSAM2. All GTSAM code lives here.

Factors (Sodhi et al. Eq. 3): a prior on the first pose; per new submap a relative xyh factor to
the previous one and a unary zpr factor, with covariances from the navigation drift per second
times the time between the two base poses (Eq. 2, 10); ICP loop closures, either full Pose3
constraints or, for degenerate alignments, partial factors that constrain only the
well-conditioned directions (Ho, Eq. 4.2-4.4). iSAM2 receives only the new factors each update.
"""

from __future__ import annotations

from functools import partial

import gtsam
import numpy as np

from vogjax.config import NavNoise
from vogjax.geometry import rigid_pose, wrap_angle
from vogjax.slam import factors
from vogjax.validation import real_array

PRIOR_SIGMAS = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])  # rad, rad, rad, m, m, m
MIN_VARIANCE, MAX_VARIANCE = 1e-12, 1e12
MAX_DURATION_S = 1e7  # four months between two base poses
# Below a millisecond the odometry factors' variances (drift per second x duration) leave iSAM2
# an indeterminate system.
MIN_DURATION_S = 1e-3
# A navigation step of more than this many drift sigmas between two base poses makes the
# odometry factor's information (step^2 / variance) swamp the rest of the graph: iSAM2's
# Cholesky then reports an indeterminate system (seen from about 1e7.5 sigmas).
MAX_STEP_SIGMAS = 1e7


def _pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(T)


def _xyh_error(measured: np.ndarray, this: gtsam.CustomFactor, values: gtsam.Values, jacobians):
    T_a = values.atPose3(this.keys()[0]).matrix()
    T_b = values.atPose3(this.keys()[1]).matrix()
    error = factors.xyh(T_a, T_b) - measured
    error[2] = wrap_angle(error[2])
    if jacobians is not None:
        jacobians[0], jacobians[1] = factors.xyh_jacobians(T_a, T_b)
    return error


def _zpr_error(measured: np.ndarray, this: gtsam.CustomFactor, values: gtsam.Values, jacobians):
    T = values.atPose3(this.keys()[0]).matrix()
    error = factors.zpr(T) - measured
    if jacobians is not None:
        jacobians[0] = factors.zpr_jacobian(T)
    return error


def _partial_error(
    between: gtsam.BetweenFactorPose3, basis: np.ndarray, this: gtsam.CustomFactor, values: gtsam.Values, jacobians
):
    """basis^T of the full Pose3 loop-closure error: GTSAM's own Jacobians, projected."""
    linear = between.linearize(values)  # unit noise: A is the plain Jacobian, b = -error
    A, b = linear.jacobian()
    if jacobians is not None:
        jacobians[0] = basis.T @ A[:, :6]
        jacobians[1] = basis.T @ A[:, 6:]
    return -(basis.T @ b)


def _covariance(name: str, covariance, size: int) -> np.ndarray:
    covariance = real_array(name, covariance)
    if covariance.shape != (size, size) or not np.all(np.isfinite(covariance)):
        raise ValueError(f"{name} must be a finite ({size}, {size}) matrix")
    if np.abs(covariance - covariance.T).max() > 1e-9 * max(np.abs(covariance).max(), 1e-300):
        raise ValueError(f"{name} must be symmetric")
    eigenvalues = np.linalg.eigvalsh(covariance)
    if eigenvalues.min() <= 0:
        raise ValueError(f"{name} must be positive definite")
    # GTSAM inverts it: sigmas below a micrometre (or microradian) or beyond a megametre
    # overflow or lose every digit in the information matrix
    if eigenvalues.min() < MIN_VARIANCE or eigenvalues.max() > MAX_VARIANCE:
        raise ValueError(
            f"{name} must have variances in [{MIN_VARIANCE:g}, {MAX_VARIANCE:g}] (sigmas from a "
            f"micrometre to a megametre), got eigenvalues {eigenvalues.min():.3g} .. {eigenvalues.max():.3g}"
        )
    return covariance


class PoseGraph:
    """Submap base poses optimised incrementally with iSAM2.

    noise: NavNoise, drift of the navigation per second
    prior_pose: (4,4) where the first submap is anchored
    """

    def __init__(self, noise: NavNoise | None = None, prior_pose=None, prior_sigmas=PRIOR_SIGMAS):
        self.noise = noise or NavNoise()
        self.prior_pose = rigid_pose("prior_pose", np.eye(4) if prior_pose is None else prior_pose)
        sigmas = real_array("prior_sigmas", prior_sigmas)
        if (
            sigmas.shape != (6,)
            or not np.all(np.isfinite(sigmas))
            or not np.all(sigmas > 0)
            or not np.all((sigmas**2 >= MIN_VARIANCE) & (sigmas**2 <= MAX_VARIANCE))
        ):
            raise ValueError(
                f"prior_sigmas must be six sigmas in [1e-6, 1e6] (rad, rad, rad, m, m, m), got {prior_sigmas!r}"
            )
        self._prior_noise = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
        self._isam = gtsam.ISAM2(gtsam.ISAM2Params())
        self._pending = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._nav: list[np.ndarray] = []
        self._estimates = np.zeros((0, 4, 4))
        self.factors: list[tuple] = []  # (kind, keys) of every factor added, for inspection

    @property
    def num_submaps(self) -> int:
        return len(self._nav)

    def add_submap(self, T_world_submap_nav, duration_s: float = 0.0) -> int:
        """A new node at the navigation pose; `duration_s`: time since the previous base pose."""
        T = rigid_pose("T_world_submap_nav", T_world_submap_nav)
        i = self.num_submaps
        if i > 0 and not (
            isinstance(duration_s, (int, float, np.integer, np.floating))
            and not isinstance(duration_s, bool)
            and np.isfinite(duration_s)
            and MIN_DURATION_S <= duration_s <= MAX_DURATION_S
        ):
            raise ValueError(
                f"duration_s must be a number of seconds in [{MIN_DURATION_S:g}, {MAX_DURATION_S:g}], "
                f"got {duration_s!r}"
            )
        if i == 0:
            self._pending.add(gtsam.PriorFactorPose3(0, _pose3(self.prior_pose), self._prior_noise))
            self.factors.append(("prior", (0,)))
            initial = self.prior_pose
        else:
            previous = self._nav[-1]
            step, variances = factors.xyh(previous, T), self.noise.xyh_variances(duration_s)
            step_sigmas = np.abs(step[:2]).max() / np.sqrt(variances[:2].min())
            if step_sigmas > MAX_STEP_SIGMAS:
                raise ValueError(
                    f"T_world_submap_nav moved {step_sigmas:.3g} drift sigmas in x-y since the "
                    f"previous base pose (at most {MAX_STEP_SIGMAS:g} in {duration_s:g} s): a jump "
                    "the pose graph cannot weigh"
                )
            xyh_noise = gtsam.noiseModel.Diagonal.Variances(variances)
            zpr_noise = gtsam.noiseModel.Diagonal.Variances(self.noise.zpr_variances(duration_s))
            self._pending.add(gtsam.CustomFactor(xyh_noise, [i - 1, i], partial(_xyh_error, step)))
            self._pending.add(gtsam.CustomFactor(zpr_noise, [i], partial(_zpr_error, factors.zpr(T))))
            self.factors += [("xyh", (i - 1, i)), ("zpr", (i,))]
            # Start from the optimised previous pose moved by the navigation's relative motion.
            initial = self._estimate(i - 1) @ np.linalg.inv(previous) @ T
        self._pending_values.insert(i, _pose3(initial))
        self._nav.append(T)
        return i

    def add_loop_closure(self, i: int, k: int, T_i_k, covariance, basis=None) -> None:
        """Constrain T_world_i^-1 T_world_k = T_i_k; `covariance` (6,6) in GTSAM order.

        basis (6,r), orthonormal columns: only these directions are constrained (partial
        factor), with covariance basis^T covariance basis.
        """
        for name, value in (("i", i), ("k", k)):
            if not isinstance(value, (int, np.integer)) or not 0 <= value < self.num_submaps:
                raise ValueError(f"{name} must be a submap id in [0, {self.num_submaps}), got {value!r}")
        if i == k:
            raise ValueError("i and k must differ")
        T_i_k = rigid_pose("T_i_k", T_i_k)
        covariance = _covariance("covariance", covariance, 6)
        if basis is None:
            self._pending.add(
                gtsam.BetweenFactorPose3(
                    int(i), int(k), _pose3(T_i_k), gtsam.noiseModel.Gaussian.Covariance(covariance)
                )
            )
            self.factors.append(("loop", (int(i), int(k))))
            return
        try:
            basis = np.asarray(basis, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("basis must be a (6, r) matrix") from None
        if (
            basis.ndim != 2
            or basis.shape[0] != 6
            or not 1 <= basis.shape[1] <= 6
            or not np.allclose(basis.T @ basis, np.eye(basis.shape[1]), atol=1e-6)
        ):
            raise ValueError("basis must be (6, r), 1 <= r <= 6, with orthonormal columns")
        unit = gtsam.noiseModel.Unit.Create(6)
        between = gtsam.BetweenFactorPose3(int(i), int(k), _pose3(T_i_k), unit)
        noise = gtsam.noiseModel.Gaussian.Covariance(basis.T @ covariance @ basis)
        self._pending.add(gtsam.CustomFactor(noise, [int(i), int(k)], partial(_partial_error, between, basis)))
        self.factors.append(("partial_loop", (int(i), int(k))))

    def update(self) -> np.ndarray:
        """Hand the new factors to iSAM2; (N,4,4) optimised poses."""
        if self._pending.size() or self._pending_values.size():
            self._isam.update(self._pending, self._pending_values)
            self._pending = gtsam.NonlinearFactorGraph()
            self._pending_values = gtsam.Values()
            estimate = self._isam.calculateEstimate()
            self._estimates = np.stack([estimate.atPose3(i).matrix() for i in range(self.num_submaps)])
        return self._estimates.copy()

    def poses(self) -> np.ndarray:
        """(N,4,4) poses as of the last update."""
        return self._estimates.copy()

    def navigation_poses(self) -> np.ndarray:
        return np.stack(self._nav) if self._nav else np.zeros((0, 4, 4))

    def marginals(self, ids) -> np.ndarray:
        """(n,6,6) marginal covariances of `ids` (GTSAM tangent order), as of the last update."""
        array = np.atleast_1d(np.asarray(ids))
        if array.ndim != 1 or (array.size and array.dtype.kind not in "iu"):
            raise ValueError(f"ids must be submap ids, got {ids!r}")
        if array.size and (array.min() < 0 or array.max() >= len(self._estimates)):
            raise ValueError(f"ids holds unknown or not yet updated submap ids (have {len(self._estimates)})")
        return np.stack([self._isam.marginalCovariance(int(i)) for i in array]) if array.size else np.zeros((0, 6, 6))

    def _estimate(self, i: int) -> np.ndarray:
        if i < len(self._estimates):
            return self._estimates[i]
        return self._pending_values.atPose3(i).matrix()
