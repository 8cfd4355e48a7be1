"""The profiling sonar of the papers: a vertical fan of beams looking ahead (Ho, thesis 4.1)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vogjax.config import SonarConfig
from vogjax.sensors.base import RangeSensor

# The sonar sits at the bow, its vertical fan looking ahead.
T_VEHICLE_SONAR = np.eye(4)
T_VEHICLE_SONAR[0, 3] = 0.9


class ProfilingSonar(RangeSensor):
    """SonarConfig's beams over fov_deg in the sensor's x-z plane, each with `subrays` rays
    across the elevation aperture.

    Parameters
    ----------
    config : SonarConfig or None, optional
        The sonar's settings (default: the papers' 96 beams over 29 degrees at 5 Hz).
    T_vehicle_sensor : (4, 4) array_like of float or None, optional
        Its mount (default `T_VEHICLE_SONAR`: at the bow).

    Raises
    ------
    ValueError
        If `config` is not a SonarConfig or the mount is not rigid.
    """

    kind = "profiling_sonar"

    def __init__(self, config: SonarConfig | None = None, T_vehicle_sensor: npt.ArrayLike | None = None):
        config = config or SonarConfig()
        if not isinstance(config, SonarConfig):
            raise ValueError(f"config must be a SonarConfig, got {type(config).__name__}")
        super().__init__(config, T_VEHICLE_SONAR if T_vehicle_sensor is None else T_vehicle_sensor)

    @property
    def beams(self) -> int:
        """Beams a scan."""
        return self.config.beams

    def beam_directions(self) -> np.ndarray:
        """The fan's beams, each `subrays` rays across the aperture.

        Returns
        -------
        (beams, subrays, 3) ndarray of float64
            Unit directions in the sensor frame (x ahead, z up).
        """
        cfg = self.config
        # one beam points along the tilt; a full circle does not repeat its first beam
        full = cfg.fov_deg >= 360.0
        offsets = (
            np.linspace(-cfg.fov_deg / 2, cfg.fov_deg / 2, cfg.beams, endpoint=not full) if cfg.beams > 1 else [0.0]
        )
        elevation = np.deg2rad(cfg.tilt_deg + np.asarray(offsets, dtype=np.float64))
        if cfg.subrays == 1:
            across = np.zeros(1)
        else:
            across = np.deg2rad(np.linspace(-cfg.aperture_deg / 2, cfg.aperture_deg / 2, cfg.subrays))
        e, a = np.meshgrid(elevation, across, indexing="ij")
        return np.stack([np.cos(e) * np.cos(a), np.sin(a), np.sin(e) * np.cos(a)], axis=-1)

    def metadata(self) -> dict:
        """What a run file records of the sonar, with the keys runs have always carried.

        Returns
        -------
        dict
            `RangeSensor.metadata`'s, and ``sonar`` and ``T_vehicle_sonar`` (so older readers
            and files agree).
        """
        return {**super().metadata(), "sonar": self.config.to_dict(), "T_vehicle_sonar": self.T_vehicle_sensor.tolist()}
