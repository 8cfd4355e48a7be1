"""The pose graph over submap base poses, on GTSAM's iSAM2. All GTSAM code lives here.

Factors (Sodhi et al. Eq. 3): a prior on the first pose; per new submap a relative xyh factor to
the previous one and a unary zpr factor, with covariances from the navigation drift per second
times the time between the two base poses (Eq. 2, 10); ICP loop closures, either full Pose3
constraints or, for degenerate alignments, partial factors that constrain only the
well-conditioned directions (Ho, Eq. 4.2-4.4). iSAM2 receives only the new factors each update.

A wrong loop closure cannot bend the graph at will (`PoseGraphConfig`): each closure is first
screened against the graph (its error at the current estimate, whitened by its covariance plus
the graph's joint marginal uncertainty of the two poses: a chi-square test, so a closure the
graph can already tell is wrong never enters), and enters with a robust loss (GTSAM's
`noiseModel.Robust`), so one that passed the screen while nothing contradicted it loses its
weight once other closures do.
"""

from __future__ import annotations

import dataclasses
import warnings
from functools import partial

import gtsam
import numpy as np
import numpy.typing as npt
from scipy import special

from vogjax.config import NavNoise
from vogjax.config.slam import PoseGraphConfig
from vogjax.geometry import inverse, log_se3, rigid_pose, wrap_angle
from vogjax.slam import factors
from vogjax.validation import real_array

PRIOR_SIGMAS = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])  # rad, rad, rad, m, m, m
MIN_VARIANCE, MAX_VARIANCE = 1e-12, 1e12
# Between two base poses: from a nanosecond (a 5 kHz sensor's two-scan submaps are 0.4 ms
# apart; iSAM2 goes on with QR where the variances leave Cholesky indeterminate) to 30,000
# years (past that the odometry variances reach MAX_VARIANCE, refused on their own)
MAX_DURATION_S = 1e12
MIN_DURATION_S = 1e-9
# A navigation step of more than this many drift sigmas between two base poses makes the
# odometry factor's information (step^2 / variance) swamp the rest of the graph: iSAM2's
# Cholesky then reports an indeterminate system (seen from about 1e7.5 sigmas).
MAX_STEP_SIGMAS = 1e7


ROBUST_ESTIMATORS = {
    "huber": gtsam.noiseModel.mEstimator.Huber,
    "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
    "geman_mcclure": gtsam.noiseModel.mEstimator.GemanMcClure,
    "dcs": gtsam.noiseModel.mEstimator.DCS,
}


@dataclasses.dataclass(frozen=True)
class ClosureCheck:
    """The verdict of `PoseGraph.add_loop_closure` on one closure.

    Attributes
    ----------
    accepted : bool
        Whether the closure entered the graph.
    distance : float
        Its Mahalanobis distance from the current estimate (the error in the constrained
        directions, whitened by the closure's covariance plus the graph's uncertainty of the
        relative pose); NaN when it was not screened.
    limit : float
        The largest distance the screen lets in (the chi-square bound for `directions` at
        `PoseGraphConfig.screen_sigmas`); NaN when it was not screened.
    directions : int
        How many directions the closure constrains (6 for a full factor).
    scale : float
        How much wider than the closure's own sigma its robust loss starts (at least 1): the
        largest ratio of the screen's sigma (closure plus graph) to the closure's own, over the
        constrained directions; 1 when it was not screened.
    """

    accepted: bool
    distance: float
    limit: float
    directions: int
    scale: float = 1.0


def screen_limit(sigmas: float, directions: int) -> float:
    """The Mahalanobis distance within which a closure passes the screen.

    Parameters
    ----------
    sigmas : float
        How many sigmas of one normal variable (3: the probability 0.9973 of lying within).
    directions : int
        Degrees of freedom of the closure's error (1 to 6).

    Returns
    -------
    float
        sqrt of the chi-square quantile with `directions` degrees of freedom at that probability.
    """
    return float(np.sqrt(special.chdtri(directions, special.erfc(sigmas / np.sqrt(2.0)))))


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


def odometry_step(
    noise: NavNoise, T_previous: npt.ArrayLike, T: npt.ArrayLike, duration_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The odometry factors between two consecutive base poses, checked as `PoseGraph.add_submap`
    checks them: (the xyh step, its variances, the zpr variances).

    Parameters
    ----------
    noise : NavNoise
        The navigation's drift per second.
    T_previous, T : (4, 4) array_like of float
        The previous and the new base pose as the navigation has them, rigid transforms.
    duration_s : float
        Time between them, seconds, in [1e-9, 1e12].

    Raises
    ------
    ValueError
        If a pose is not rigid, `duration_s` is not a number in [1e-9, 1e12] s, the odometry
        variances (the drift times `duration_s`) exceed 1e12, or the step is more than 1e7
        drift sigmas in x-y (a jump the pose graph cannot weigh).
    """
    T_previous = rigid_pose("T_previous", T_previous)
    T = rigid_pose("T_world_submap_nav", T)
    if not (
        isinstance(duration_s, (int, float, np.integer, np.floating))
        and not isinstance(duration_s, bool)
        and np.isfinite(duration_s)
        and MIN_DURATION_S <= duration_s <= MAX_DURATION_S
    ):
        raise ValueError(
            f"duration_s must be a number of seconds in [{MIN_DURATION_S:g}, {MAX_DURATION_S:g}], got {duration_s!r}"
        )
    with np.errstate(over="ignore"):
        step, variances = factors.xyh(T_previous, T), noise.xyh_variances(duration_s)
        zpr_variances = noise.zpr_variances(duration_s)
    if not np.all(np.r_[variances, zpr_variances] <= MAX_VARIANCE):  # inf too: NaN marginals
        raise ValueError(
            f"NavNoise over duration_s {duration_s:g} s gives odometry variances above "
            f"{MAX_VARIANCE:g} (xyh {variances}, zpr {zpr_variances}): a drift the pose graph cannot weigh"
        )
    step_sigmas = np.abs(step[:2]).max() / np.sqrt(variances[:2].min())
    if step_sigmas > MAX_STEP_SIGMAS:
        raise ValueError(
            f"T_world_submap_nav moved {step_sigmas:.3g} drift sigmas in x-y since the "
            f"previous base pose (at most {MAX_STEP_SIGMAS:g} in {duration_s:g} s at NavNoise "
            f"sigma2_x {noise.sigma2_x:g}, sigma2_y {noise.sigma2_y:g} m^2/s): a jump "
            "the pose graph cannot weigh (a wrong pose, or a drift set too small)"
        )
    return step, variances, zpr_variances


class PoseGraph:
    """Submap base poses optimised incrementally with iSAM2.

    Node i is submap i's base pose ``T_world_submap``. Factors (Sodhi et al. Eq. 3): a prior on
    the first pose; per new submap a relative x-y-yaw factor to the previous one and a unary
    depth-pitch-roll factor, their covariances the navigation's drift per second times the time
    between the two base poses; loop closures (`add_loop_closure`), screened against the graph
    and with a robust loss (`PoseGraphConfig`). iSAM2 receives only the new factors each
    `update`. Covariances and tangents are in GTSAM's Pose3 order: rotation, then translation.

    Parameters
    ----------
    noise : NavNoise or None, optional
        Drift of the navigation per second (the odometry factors' covariances; default:
        ``NavNoise()``).
    prior_pose : (4, 4) array_like of float or None, optional
        Where the first submap is anchored, a rigid transform (None: the identity).
    prior_sigmas : (6,) array_like of float, optional
        Sigmas of the anchor (rad, rad, rad, m, m, m), each in [1e-6, 1e6] (default: 1e-4 rad
        and 1e-3 m).
    config : PoseGraphConfig or None, optional
        How loop closures enter: the screen and the robust loss (default:
        ``PoseGraphConfig()``).

    Attributes
    ----------
    config : PoseGraphConfig
        The loop-closure settings.
    noise : NavNoise
        The navigation's drift.
    prior_pose : (4, 4) ndarray of float64
        The anchor of the first submap.
    factors : list of tuple
        (kind, keys) of every factor added, for inspection: kind "prior", "xyh", "zpr", "loop"
        or "partial_loop", keys the submap ids it ties.
    factorization : str
        iSAM2's: "CHOLESKY" (GTSAM's default), or "QR" from the first `update` that Cholesky
        found indeterminate (sigmas spanning too many orders for it; a RuntimeWarning says so).

    Raises
    ------
    ValueError
        When an argument is not what it should be (named in the message).
    """

    def __init__(
        self,
        noise: NavNoise | None = None,
        prior_pose: npt.ArrayLike | None = None,
        prior_sigmas: npt.ArrayLike = PRIOR_SIGMAS,
        config: PoseGraphConfig | None = None,
    ):
        self.config = config = PoseGraphConfig() if config is None else config
        if not isinstance(config, PoseGraphConfig):
            raise ValueError(f"config must be a PoseGraphConfig, got {type(config).__name__}")
        if noise is not None and not isinstance(noise, NavNoise):
            raise ValueError(f"noise must be a NavNoise, got {type(noise).__name__}")
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
        self.factorization = "CHOLESKY"
        self._committed = gtsam.NonlinearFactorGraph()  # every factor iSAM2 holds, to refactor from
        self._pending = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._nav: list[np.ndarray] = []
        self._estimates = np.zeros((0, 4, 4))
        self._relative: dict[tuple[int, int], np.ndarray] = {}  # (i, k) -> covariance, this update's
        self.factors: list[tuple] = []  # (kind, keys) of every factor added, for inspection

    @property
    def num_submaps(self) -> int:
        """Nodes in the graph, optimised or not yet (their ids are 0 to num_submaps - 1)."""
        return len(self._nav)

    def add_submap(self, T_world_submap_nav: npt.ArrayLike, duration_s: float = 0.0) -> int:
        """Add a node at a submap's navigation base pose, tied to the previous one by odometry.

        The node starts from the optimised previous pose moved by the navigation's relative
        motion; it is optimised at the next `update`.

        Parameters
        ----------
        T_world_submap_nav : (4, 4) array_like of float
            The submap's base pose as the navigation has it, a rigid transform.
        duration_s : float, optional
            Time since the previous base pose, seconds, in [1e-9, 1e12] (ignored for the first
            node, which gets the prior): the odometry factors' covariances grow with it.

        Returns
        -------
        int
            The new node's submap id.

        Raises
        ------
        ValueError
            Before anything changes: a pose that is not rigid, `duration_s` not a number in
            [1e-9, 1e12] s, odometry variances (the navigation's drift times `duration_s`)
            above 1e12, or a step from the previous base pose of more than 1e7 drift sigmas
            in x-y (a jump the pose graph cannot weigh).
        """
        T = rigid_pose("T_world_submap_nav", T_world_submap_nav)
        i = self.num_submaps
        if i == 0:
            self._pending.add(gtsam.PriorFactorPose3(0, _pose3(self.prior_pose), self._prior_noise))
            self.factors.append(("prior", (0,)))
            initial = self.prior_pose
        else:
            previous = self._nav[-1]
            step, variances, zpr_variances = odometry_step(self.noise, previous, T, duration_s)
            xyh_noise = gtsam.noiseModel.Diagonal.Variances(variances)
            zpr_noise = gtsam.noiseModel.Diagonal.Variances(zpr_variances)
            self._pending.add(gtsam.CustomFactor(xyh_noise, [i - 1, i], partial(_xyh_error, step)))
            self._pending.add(gtsam.CustomFactor(zpr_noise, [i], partial(_zpr_error, factors.zpr(T))))
            self.factors += [("xyh", (i - 1, i)), ("zpr", (i,))]
            # Start from the optimised previous pose moved by the navigation's relative motion.
            initial = self._estimate(i - 1) @ np.linalg.inv(previous) @ T
        self._pending_values.insert(i, _pose3(initial))
        self._nav.append(T)
        return i

    def add_loop_closure(
        self, i: int, k: int, T_i_k: npt.ArrayLike, covariance: npt.ArrayLike, basis: npt.ArrayLike | None = None
    ) -> ClosureCheck:
        """Constrain T_world_i^-1 T_world_k = T_i_k, if the screen lets the closure in.

        Parameters
        ----------
        i, k : int
            Submap ids, different, both in the graph.
        T_i_k : (4, 4) array_like of float
            Rigid transform: where submap k's base pose sits in submap i's frame.
        covariance : (6, 6) array_like of float
            Symmetric positive definite, GTSAM tangent order (rotation, translation; rad and
            m), its eigenvalues in [1e-12, 1e12] (sigmas from a micrometre to a megametre).
        basis : (6, r) array_like of float or None, optional
            Orthonormal columns: only these directions are constrained (a partial factor, with
            covariance basis^T covariance basis); None constrains all six.

        Returns
        -------
        ClosureCheck
            Whether it entered, and its distance from the estimate against the screen's limit.
            The screen judges it against the graph as of the last `update()` (the graph is
            updated first when i or k was added since). With `robust_loss` it enters with that
            loss; a closure refused leaves the graph as it was.

        Raises
        ------
        ValueError
            On bad ids, a non-rigid T_i_k, a covariance that is not a valid one, or a basis
            that is not (6, r) orthonormal; nothing is changed then.
        """
        i, k = self._pair(i, k)
        T_i_k = rigid_pose("T_i_k", T_i_k)
        covariance = _covariance("covariance", covariance, 6)
        if basis is not None:
            basis = real_array("basis", basis)  # a complex or bool basis is no direction
            if (
                basis.ndim != 2
                or basis.shape[0] != 6
                or not 1 <= basis.shape[1] <= 6
                or not np.all(np.isfinite(basis))
                or not np.allclose(basis.T @ basis, np.eye(basis.shape[1]), atol=1e-6)
            ):
                raise ValueError("basis must be (6, r), 1 <= r <= 6, with orthonormal columns")
        directions = 6 if basis is None else basis.shape[1]
        check = ClosureCheck(True, np.nan, np.nan, directions)
        if self.config.screen == "graph":
            check = self._screen(i, k, T_i_k, covariance, basis)
            if not check.accepted:
                return check
        if basis is None:
            noise = self._closure_noise(covariance, check.scale)
            self._pending.add(gtsam.BetweenFactorPose3(i, k, _pose3(T_i_k), noise))
            self.factors.append(("loop", (i, k)))
            return check
        unit = gtsam.noiseModel.Unit.Create(6)
        between = gtsam.BetweenFactorPose3(i, k, _pose3(T_i_k), unit)
        noise = self._closure_noise(basis.T @ covariance @ basis, check.scale)
        self._pending.add(gtsam.CustomFactor(noise, [i, k], partial(_partial_error, between, basis)))
        self.factors.append(("partial_loop", (i, k)))
        return check

    def _closure_noise(self, covariance: np.ndarray, scale: float):
        """A closure's noise model: Gaussian, or wrapped in the configured robust loss of width
        robust_width x scale (sigmas of its whitened error). iSAM2 weighs a robust factor at the
        estimate it linearises it at and re-weighs it only when it relinearises it, so a
        closure that enters far from the estimate in its own sigmas (after a long loop, the
        graph still uncertain) would start, and stay, at next to no weight: its loss starts
        as wide as the uncertainty it was screened with (`ClosureCheck.scale`)."""
        gaussian = gtsam.noiseModel.Gaussian.Covariance(covariance)
        if self.config.robust_loss == "none":
            return gaussian
        width = self.config.robust_width * scale
        # DCS's parameter is a squared error (weight 1 up to e^2 = phi)
        parameter = width**2 if self.config.robust_loss == "dcs" else width
        estimator = ROBUST_ESTIMATORS[self.config.robust_loss].Create(parameter)
        return gtsam.noiseModel.Robust.Create(estimator, gaussian)

    def _screen(self, i: int, k: int, T_i_k: np.ndarray, covariance: np.ndarray, basis) -> ClosureCheck:
        """The closure's Mahalanobis distance from the estimate against the screen's limit: the
        error log(P^-1 T_i_k) of the estimate P = T_i^-1 T_k has covariance
        `relative_covariance(i, k)` plus the closure's noise, both projected on basis."""
        P_covariance = self._relative_covariance(i, k)
        P = inverse(self._estimates[i]) @ self._estimates[k]
        B = np.eye(6) if basis is None else basis
        innovation = B.T @ (P_covariance + covariance) @ B
        error = B.T @ log_se3(inverse(P) @ T_i_k)
        distance = float(np.sqrt(max(error @ np.linalg.solve(innovation, error), 0.0)))
        limit = screen_limit(self.config.screen_sigmas, B.shape[1])
        # the largest ratio of innovation to closure variance over all directions: the
        # eigenvalues of C^-1/2 S C^-1/2, with C = B^T covariance B
        own = np.linalg.cholesky(B.T @ covariance @ B)
        whitened = np.linalg.solve(own, np.linalg.solve(own, innovation).T)
        scale = float(np.sqrt(max(np.linalg.eigvalsh((whitened + whitened.T) / 2).max(), 1.0)))
        return ClosureCheck(bool(distance <= limit), distance, limit, B.shape[1], scale)

    def relative_covariance(self, i: int, k: int) -> npt.NDArray[np.float64]:
        """How well the graph knows where submap k sits in submap i's frame, as of the last
        `update` (the graph is updated first when i or k was added since).

        The relative pose P = T_world_i^-1 T_world_k moves by xi_k - Ad(P^-1) xi_i under
        GTSAM's right perturbations T Exp(xi), so its covariance is A J A^T with A =
        [-Ad(P^-1), I] and J iSAM2's joint marginal of (i, k). What the loop-closure screen
        judges a closure of the pair against, and what bounds the detector's search for one
        (`LoopClosureDetector.detect`); computed once per pair and update, for both.

        Parameters
        ----------
        i, k : int
            Submap ids, different, both in the graph.

        Returns
        -------
        (6, 6) ndarray of float64
            The covariance of P in its right tangent, GTSAM order (rotation, then translation;
            rad and m), a copy.

        Raises
        ------
        ValueError
            If `i` or `k` is not a submap id of the graph, or they are the same.
        """
        return self._relative_covariance(*self._pair(i, k)).copy()

    def _pair(self, i, k) -> tuple[int, int]:
        """Two different submap ids of the graph, as ints (ValueError naming the one that is not)."""
        for name, value in (("i", i), ("k", k)):
            if (
                isinstance(value, (bool, np.bool_))
                or not isinstance(value, (int, np.integer))
                or not 0 <= value < self.num_submaps
            ):
                raise ValueError(f"{name} must be a submap id in [0, {self.num_submaps}), got {value!r}")
        if i == k:
            raise ValueError("i and k must differ")
        return int(i), int(k)

    def _relative_covariance(self, i: int, k: int) -> np.ndarray:
        if max(i, k) >= len(self._estimates):  # a node not yet optimised: no estimate to judge by
            self.update()
        if (i, k) not in self._relative:
            P = inverse(self._estimates[i]) @ self._estimates[k]
            joint = self._isam.jointMarginalCovariance([i, k]).fullMatrix()
            A = np.hstack([-gtsam.Pose3(inverse(P)).AdjointMap(), np.eye(6)])
            self._relative[(i, k)] = A @ joint @ A.T
        return self._relative[(i, k)]

    def update(self) -> npt.NDArray[np.float64]:
        """Hand the new factors and nodes to iSAM2 and read the estimate back.

        Returns
        -------
        (N, 4, 4) ndarray of float64
            The optimised base poses ``T_world_submap`` of all N submaps, a copy.
        """
        if self._pending.size() or self._pending_values.size():
            try:
                self._isam.update(self._pending, self._pending_values)
            except RuntimeError as error:
                if self.factorization == "QR" or "ndetermina" not in str(error):
                    raise
                self._refactor_with_qr()
            self._committed.push_back(self._pending)
            self._relative.clear()
            self._pending = gtsam.NonlinearFactorGraph()
            self._pending_values = gtsam.Values()
            estimate = self._isam.calculateEstimate()
            self._estimates = np.stack([estimate.atPose3(i).matrix() for i in range(self.num_submaps)])
        return self._estimates.copy()

    def _refactor_with_qr(self) -> None:
        """Start iSAM2 afresh on QR, with every factor so far and the pending ones.

        iSAM2's default Cholesky factorization squares the whitened Jacobians, so a graph whose
        sigmas span many orders (a loose prior beside tight odometry, a yaw drift of radians
        over hundreds of metres: valid settings, each) leaves it a system it calls
        indeterminate, and the failed update leaves the old iSAM2 unusable. QR works on the
        Jacobians themselves and solves those graphs; the papers' graphs never get here, so
        their poses keep Cholesky's bits. From here on the graph stays on QR
        (`factorization`)."""
        params = gtsam.ISAM2Params()
        params.setFactorization("QR")
        values = gtsam.Values()
        for i, T in enumerate(self._estimates):
            values.insert(i, _pose3(T))
        values.insert(self._pending_values)
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(self._committed)
        graph.push_back(self._pending)
        self._isam = gtsam.ISAM2(params)
        self.factorization = "QR"
        warnings.warn(
            "the pose graph's sigmas span too many orders for iSAM2's Cholesky factorization "
            "(GTSAM: indeterminate linear system); it goes on with QR",
            RuntimeWarning,
            stacklevel=3,
        )
        self._isam.update(graph, values)

    def poses(self) -> npt.NDArray[np.float64]:
        """The optimised poses as of the last `update`.

        Returns
        -------
        (N, 4, 4) ndarray of float64
            ``T_world_submap`` of the N submaps optimised so far, a copy.
        """
        return self._estimates.copy()

    def navigation_poses(self) -> npt.NDArray[np.float64]:
        """The navigation's base poses, as added.

        Returns
        -------
        (N, 4, 4) ndarray of float64
            ``T_world_submap_nav`` of every node, in the order added.
        """
        return np.stack(self._nav) if self._nav else np.zeros((0, 4, 4))

    def marginals(self, ids: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Marginal covariances of some poses, as of the last `update`.

        What `GlobalMap.update_poses` takes (S2 of Algorithm 1).

        Parameters
        ----------
        ids : int or (n,) array_like of int
            Submap ids, updated at least once.

        Returns
        -------
        (n, 6, 6) ndarray of float64
            iSAM2's marginal covariance of each pose, GTSAM tangent order (rotation, then
            translation; rad and m).

        Raises
        ------
        ValueError
            If `ids` are not integers, or hold ids unknown or not yet updated.
        """
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
