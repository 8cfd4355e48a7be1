"""Range sensors: their beams, what a run file stores of them, and rays from stored scans.

sonar = vj.sensors.ProfilingSonar(vj.SonarConfig(range_noise_m=0.02))
sonar.beam_directions()                       # (B, U, 3), sensor frame
vj.sensors.from_metadata(dataset.metadata)    # the sensor a run was recorded with
"""

from __future__ import annotations

import numpy as np

from vogjax.config import PointCloudConfig, SonarConfig
from vogjax.config.lidar import LidarConfig
from vogjax.sensors.base import RangeSensor, mapped_beams, world_rays
from vogjax.sensors.lidar import T_VEHICLE_LIDAR, SpinningLidar
from vogjax.sensors.point_cloud import PointCloudSensor
from vogjax.sensors.sonar import T_VEHICLE_SONAR, ProfilingSonar

KINDS = {
    ProfilingSonar.kind: (ProfilingSonar, SonarConfig),
    PointCloudSensor.kind: (PointCloudSensor, PointCloudConfig),
    SpinningLidar.kind: (SpinningLidar, LidarConfig),
}


def from_metadata(metadata: dict) -> RangeSensor:
    """The sensor a run's metadata describes (runs that predate the `sensor` key carry a
    profiling sonar under `sonar`).

    Parameters
    ----------
    metadata : dict
        The run's metadata (`RangeSensor.metadata` wrote it).

    Returns
    -------
    RangeSensor
        The sensor, with its settings and mount.

    Raises
    ------
    ValueError
        If it names no known sensor or describes it wrongly.
    """
    kind = metadata.get("sensor", ProfilingSonar.kind)
    if not isinstance(kind, str) or kind not in KINDS:
        raise ValueError(f"metadata names an unknown sensor {repr(kind)[:80]} (known: {', '.join(KINDS)})")
    cls, config_cls = KINDS[kind]
    values = metadata.get("sensor_config", metadata.get("sonar", {}))
    mount = metadata.get("T_vehicle_sensor", metadata.get("T_vehicle_sonar"))
    try:
        config = config_cls.from_dict(values, where="metadata.sensor_config")
        return cls(config, None if mount is None else np.asarray(mount, dtype=np.float64))
    except (TypeError, ValueError) as error:
        raise ValueError(f"metadata describes its sensor wrongly: {error}") from None


def as_sensor(sensor: RangeSensor | SonarConfig) -> RangeSensor:
    """A RangeSensor as given, or a ProfilingSonar for a SonarConfig.

    Parameters
    ----------
    sensor : RangeSensor or SonarConfig
        The sensor, or a sonar's settings.

    Returns
    -------
    RangeSensor
        The sensor.

    Raises
    ------
    ValueError
        If `sensor` is neither.
    """
    if isinstance(sensor, RangeSensor):
        return sensor
    if isinstance(sensor, SonarConfig):
        return ProfilingSonar(sensor)
    raise ValueError(f"sensor must be a vogjax.sensors.RangeSensor or a SonarConfig, got {type(sensor).__name__}")


__all__ = [
    "KINDS",
    "T_VEHICLE_LIDAR",
    "T_VEHICLE_SONAR",
    "PointCloudSensor",
    "ProfilingSonar",
    "RangeSensor",
    "SpinningLidar",
    "as_sensor",
    "from_metadata",
    "mapped_beams",
    "world_rays",
]
