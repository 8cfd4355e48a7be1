"""Settings of a recorded range sensor whose beams change from scan to scan (a lidar's point
cloud, a laser scanner's fan or a depth camera's pixels, imported from a ROS bag)."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, integer, non_negative, positive, text


@dataclasses.dataclass(frozen=True)
class PointCloudConfig(Config):
    """Settings of a recorded point-cloud, laser-scan or depth-camera sensor, as a bag import derives them.

    Attributes
    ----------
    message : str
        The ROS message the scans came from: "PointCloud2", "LaserScan" or "Image" (a depth
        camera's).
    beams : int
        Beams per stored scan (scans with fewer real beams are padded with copies of one of their
        own beams, which changes no map).
    rate_hz : float
        Mean scans per second of the recording (10 when it holds a single scan).
    min_range_m : float
        Returns below it were dropped as invalid (LaserScan's range_min), metres.
    max_range_m : float
        The sensor's reach, metres: LaserScan's range_max, or for a point cloud the farthest
        return (or what the importer was told); beams without a return clear free space up to it.

    Raises
    ------
    ValueError
        If a setting is out of its range or `min_range_m` is not below `max_range_m`.
    """

    message: str = text("PointCloud2", ("PointCloud2", "LaserScan", "Image"))
    beams: int = integer(1, low=1)
    rate_hz: float = positive(10.0)
    min_range_m: float = non_negative(0.0)
    max_range_m: float = positive(100.0)

    def check(self) -> None:
        if not self.min_range_m < self.max_range_m:
            raise ValueError("PointCloudConfig.min_range_m must lie in [0, max_range_m)")
