"""Settings of the confidence-rich map (Agha-mohammadi, *Confidence-aware Occupancy Grid Mapping*)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import numpy.typing as npt

from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.config.schema import Config, integer, number, positive, probability, text


@dataclasses.dataclass(frozen=True)
class CrmConfig(Config):
    """Settings of the confidence-rich map (`vj.ConfidenceMap`).

    Each voxel holds a discretised distribution over its occupancy level m; a range reading
    updates the voxels of its beam's cone by the paper's inverse cause model.

    Attributes
    ----------
    voxel_size : float
        Edge of a voxel, metres; voxel k covers ``[k*s, (k+1)*s)`` on each axis.
    max_range : float
        Readings longer than this are "no return" (the cause lies beyond the sensor's reach),
        metres. At most MAX_RANGE_VOXELS (4096) voxels, as for `MapConfig`: a beam's cone is walked
        and stored voxel by voxel.
    range_sigma_m : float
        Standard deviation of the range noise, metres (the paper's R = sigma^2; its 2D experiment
        has R = 0.04 m^2, sigma = 0.2 m); at least a micrometre: where the cone's few sigmas
        round away against the range, a return would explain nothing, its voxels marked
        observed but left at the prior.
    cause_range : str
        Where along a beam a cause voxel puts its reading: "chord", anywhere on the beam's chord
        through it (a surface somewhere inside the voxel: scenes, sonar), or "centre", at the
        distance of its centre (the paper's Eq. 18: solid cells, as in its 2D experiment).
    num_bins : int
        Points of the discretised distribution of a voxel's occupancy level m, at
        m_k = k / (num_bins - 1): both ends included, so a voxel can be certainly free (m = 0) or
        certainly occupied (m = 1). 16 gives means within 0.014 of a 64-bin filter's at 73 bytes
        per voxel (benchmarks/bench_crm.py).
    spurious_probability : float
        Chance that a return is spurious (uniform over (0, max_range), caused by nothing in the
        map); 0 is the paper's model. Above 0 it tempers every update, but with the uniform prior
        (bounce probability 0.5 per unknown voxel) long readings through unexplored space then
        look spurious and the map stops growing into it: raise it only for maps of known free
        space.
    cone_sigmas : float
        Voxels up to this many `range_sigma_m` past a return are candidate causes of it; farther
        ones could cause it with a probability below Q(cone_sigmas) and are neither causes nor
        updated.
    bin_floor : float
        After every scan no bin of an updated voxel is left below this probability (then the
        bins are renormalised), the analogue of OctoMap's clamping: a wrong certainty can still be
        undone by later evidence.
    occupied_threshold : float
        Mean occupancy at or above which a voxel is OCCUPIED.
    free_threshold : float
        Mean occupancy at or below which a voxel is FREE (between the thresholds: UNKNOWN).

    Raises
    ------
    ValueError
        If a setting is out of its range, `free_threshold` exceeds `occupied_threshold`,
        ``bin_floor * num_bins`` is not below 0.5, or `max_range` exceeds 4096 voxels.
    """

    voxel_size: float = number(0.1, low=1e-4, high=1e3)
    max_range: float = positive(11.0)
    range_sigma_m: float = number(0.05, low=1e-6)
    cause_range: str = text("chord", ("chord", "centre"))
    num_bins: int = integer(16, low=2, high=64)
    spurious_probability: float = number(0.0, low=0, high=1, high_open=True)
    cone_sigmas: float = number(3.0, low=0.5, high=10.0)
    bin_floor: float = number(1e-6, low=0, high=0.01, low_open=True)
    occupied_threshold: float = probability(0.7)
    free_threshold: float = probability(0.3)

    def check(self) -> None:
        if not self.free_threshold <= self.occupied_threshold:
            raise ValueError("CrmConfig.free_threshold must not exceed CrmConfig.occupied_threshold")
        if not self.bin_floor * self.num_bins < 0.5:
            raise ValueError("CrmConfig.bin_floor times CrmConfig.num_bins must stay below 0.5")
        if self.max_range > MAX_RANGE_VOXELS * self.voxel_size:
            raise ValueError(
                f"CrmConfig.max_range must be at most {MAX_RANGE_VOXELS} voxels "
                f"({MAX_RANGE_VOXELS * self.voxel_size:g} m at voxel_size {self.voxel_size:g} m): "
                f"each beam's cone is stored voxel by voxel, got {self.max_range!r}"
            )

    # ---------------------------------------------------------------- the discretisation
    @functools.cached_property
    def bin_centres(self) -> npt.NDArray[np.float32]:
        """(num_bins,) float32 occupancy levels m_k = k / (num_bins - 1), as the kernels compute them."""
        k = np.arange(self.num_bins, dtype=np.float32)
        return k / np.float32(self.num_bins - 1)

    @functools.cached_property
    def prior(self) -> npt.NDArray[np.float32]:
        """(num_bins,) float32 prior distribution: uniform over the levels."""
        return np.full(self.num_bins, np.float32(1.0) / np.float32(self.num_bins), np.float32)

    @functools.cached_property
    def prior_mean(self) -> np.float32:
        """Mean occupancy level of the prior (0.5), as the kernels compute it."""
        return moments(self.prior, self.bin_centres)[0]

    @functools.cached_property
    def prior_variance(self) -> np.float32:
        """Variance of the prior's occupancy level, as the kernels compute it."""
        return moments(self.prior, self.bin_centres)[1]


def moments(
    bins: npt.ArrayLike, centres: npt.NDArray[np.float32]
) -> tuple[np.float32 | npt.NDArray[np.float32], np.float32 | npt.NDArray[np.float32]]:
    """Mean and variance of discretised distributions, the way the kernels compute them.

    Sums are accumulated in float64 in bin order and rounded to float32.

    Parameters
    ----------
    bins : (..., K) array_like of float
        Probabilities of the occupancy levels, one distribution per leading index (rounded to
        float32 first).
    centres : (K,) ndarray of float
        The occupancy levels (`CrmConfig.bin_centres`).

    Returns
    -------
    mean : float32 or (...) ndarray of float32
        The distributions' means (a scalar for a single distribution).
    variance : float32 or (...) ndarray of float32
        Their variances.
    """
    bins = np.asarray(bins, np.float32).astype(np.float64)
    m = centres.astype(np.float64)
    mean = np.zeros(bins.shape[:-1])
    for k in range(bins.shape[-1]):
        mean = mean + bins[..., k] * m[k]
    variance = np.zeros(bins.shape[:-1])
    for k in range(bins.shape[-1]):
        d = m[k] - mean
        variance = variance + bins[..., k] * d * d
    return np.float32(mean) if np.ndim(mean) == 0 else mean.astype(np.float32), np.float32(variance) if np.ndim(
        variance
    ) == 0 else variance.astype(np.float32)
