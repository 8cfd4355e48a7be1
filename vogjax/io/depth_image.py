"""Depth cameras: a sensor_msgs/Image of depths and its sensor_msgs/CameraInfo as range beams.

Each pixel (u, v) that holds a depth looks along the pinhole ray through it: with K the
camera matrix of its CameraInfo, the ray's normalised coordinates are ``K^-1 (u, v, 1)``
(pixel centres at integer coordinates, as ROS and OpenCV count them), undistorted where the
CameraInfo carries a plumb_bob distortion, and the depth is the point's z (along the optical
axis), not its range: the point is ``depth * (x, y, 1)`` in the image's frame (an optical frame:
z ahead, x right, y down). `--stride N` takes every Nth pixel of every Nth row, from the first.

Encodings: 16UC1 (millimetres, 0: no depth) and 32FC1 (metres; 0, NaN and infinities: no
depth), in either byte order. A pixel without a depth is an invalid beam (dropped, counted):
a depth camera reports "too far" and "not seen" alike, so no pixel clears free space.

Distortion: none (every coefficient 0, any model name) or plumb_bob (k1, k2, p1, p2, k3, the
image as the camera saw it), undistorted per pixel by Newton's method and checked to reproject
onto its pixel; other models with non-zero coefficients (rational_polynomial, equidistant)
are refused, as are binned or cropped (ROI) images.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt

from vogjax.config.sensing import MAX_BEAMS

ENCODINGS = {"16UC1": ("u2", 1e-3), "32FC1": ("f4", 1.0)}  # encoding: (sample type, metres per unit)
MAX_SIDE = 1 << 16  # pixels per image side: no depth camera has more
_UNDISTORT_ITERATIONS = 30
_UNDISTORT_TOLERANCE = 1e-12  # normalised image coordinates: 1e-9 px at a 1000 px focal length


@dataclasses.dataclass(frozen=True)
class Camera:
    """A depth camera as its CameraInfo describes it.

    Attributes
    ----------
    frame : str
        The frame of its images (an optical frame).
    width, height : int
        Image size, pixels.
    K : (3, 3) ndarray of float64
        The camera matrix (fx, skew, cx; fy, cy).
    distortion_model : str
        The CameraInfo's model name ("plumb_bob", ...; "" when it names none).
    D : tuple of float
        Its coefficients.
    """

    frame: str
    width: int
    height: int
    K: npt.NDArray[np.float64]
    distortion_model: str
    D: tuple[float, ...]

    @property
    def undistorts(self) -> bool:
        """Whether pixels are undistorted (plumb_bob with a non-zero coefficient)."""
        return any(d != 0.0 for d in self.D)

    def describe(self) -> dict[str, Any]:
        """What a run's metadata records of the camera (JSON-able)."""
        return {
            "frame": self.frame,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "distortion_model": self.distortion_model,
            "D": list(self.D),
            "undistorted": self.undistorts,
        }

    def rays(self, stride: int) -> npt.NDArray[np.float64]:
        """The rays of every `stride`-th pixel of every `stride`-th row, row by row.

        Parameters
        ----------
        stride : int
            Pixels skipped in each direction (1: every pixel).

        Returns
        -------
        (M, 3) ndarray of float64
            ``(x, y, 1)``: undistorted normalised coordinates of each pixel, so that depth
            times the ray is the point.

        Raises
        ------
        ValueError
            If `stride` is not a positive integer, or the distortion does not invert at some
            pixel (coefficients that fold the image).
        """
        check_stride(stride)
        v, u = np.meshgrid(
            np.arange(0, self.height, stride, dtype=np.float64),
            np.arange(0, self.width, stride, dtype=np.float64),
            indexing="ij",
        )
        pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
        normalised = np.linalg.solve(self.K, pixels.T).T
        if self.undistorts:
            normalised[:, :2] = undistort(normalised[:, :2], self.D)
        return normalised


def distort(xy: npt.ArrayLike, D: tuple[float, ...]) -> npt.NDArray[np.float64]:
    """The plumb_bob (Brown-Conrady, OpenCV's five-coefficient) distortion of normalised points.

    Parameters
    ----------
    xy : (N, 2) array_like of float
        Undistorted normalised image coordinates.
    D : tuple of float
        k1, k2, p1, p2[, k3].

    Returns
    -------
    (N, 2) ndarray of float64
        The distorted coordinates.
    """
    k1, k2, p1, p2, k3 = (tuple(D) + (0.0,))[:5]
    x, y = np.asarray(xy, dtype=np.float64).T
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.stack(
        [x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y],
        axis=1,
    )


def undistort(distorted: npt.ArrayLike, D: tuple[float, ...]) -> npt.NDArray[np.float64]:
    """The inverse of `distort`, by Newton's method from the distorted points.

    Parameters
    ----------
    distorted : (N, 2) array_like of float
        Distorted normalised image coordinates.
    D : tuple of float
        k1, k2, p1, p2[, k3].

    Returns
    -------
    (N, 2) ndarray of float64
        Points that `distort` maps onto `distorted` within 1e-12.

    Raises
    ------
    ValueError
        If Newton's method does not converge at some point, or converges past the fold of the
        distortion (where the radial factor, or its growth with the radius, is not positive).
    """
    k1, k2, p1, p2, k3 = (tuple(D) + (0.0,))[:5]
    target = np.asarray(distorted, dtype=np.float64)
    xy = target.copy()
    for _ in range(_UNDISTORT_ITERATIONS):
        x, y = xy.T
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        slope = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
        a = radial + 2 * x * x * slope + 2 * p1 * y + 6 * p2 * x
        b = 2 * x * y * slope + 2 * p1 * x + 2 * p2 * y
        d = radial + 2 * y * y * slope + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * b
        residual = distort(xy, D) - target
        # a solution where the radial distortion has turned (radial or its growth with r not
        # positive) lies past the fold of the image: another pixel's point, not this one's
        unfolded = (radial > 0) & (radial + 2 * r2 * slope > 0) & (det > 0)
        if np.all(np.abs(residual) <= _UNDISTORT_TOLERANCE) and np.all(unfolded):
            return xy
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.stack([d * residual[:, 0] - b * residual[:, 1], a * residual[:, 1] - b * residual[:, 0]], axis=1)
            xy = xy - step / det[:, None]
        if not np.all(np.isfinite(xy)):
            break
    worst = target[int(np.nanargmax(np.abs(distort(xy, D) - target).max(axis=1)))] if np.all(np.isfinite(xy)) else None
    at = "" if worst is None else f" (at normalised point {worst[0]:.3g}, {worst[1]:.3g})"
    raise ValueError(f"the plumb_bob distortion {list(D)} does not invert over the image{at}")


def camera_from_info(msg: Any, where: str) -> Camera:
    """A Camera from one sensor_msgs/CameraInfo, checked.

    Parameters
    ----------
    msg : sensor_msgs/msg/CameraInfo
        As rosbags deserialises it (ROS 1's K, D or ROS 2's k, d).
    where : str
        What an error names (flag and topic).

    Returns
    -------
    Camera

    Raises
    ------
    ValueError
        Naming `where` when the size is zero or past 65536, K is not a finite camera matrix
        with positive focal lengths, the image is binned or cropped (ROI), or the distortion
        is one vogjax does not undistort.
    """
    K = np.asarray(_field(msg, "k"), dtype=np.float64)
    if K.size != 9:
        raise ValueError(f"{where}: CameraInfo's K holds {K.size} numbers, not the 9 of a 3 x 3 camera matrix")
    K = K.reshape(3, 3)
    D = tuple(float(d) for d in np.asarray(_field(msg, "d"), dtype=np.float64).ravel())
    width, height = int(msg.width), int(msg.height)
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        raise ValueError(f"{where}: CameraInfo has image size {width} x {height}")
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and np.all(K[2] == [0, 0, 1])):
        raise ValueError(f"{where}: CameraInfo's K {K.ravel().tolist()} is not a camera matrix (fx, fy > 0)")
    binning = (int(msg.binning_x), int(msg.binning_y))
    roi = msg.roi
    cropped = (int(roi.x_offset), int(roi.y_offset)) != (0, 0) or int(roi.width) not in (0, width)
    cropped = cropped or int(roi.height) not in (0, height)
    if any(b > 1 for b in binning) or cropped:
        raise ValueError(f"{where}: CameraInfo describes a binned or cropped (ROI) image, which is not supported")
    model = str(msg.distortion_model)
    if not all(np.isfinite(D)):
        raise ValueError(f"{where}: CameraInfo's distortion coefficients {list(D)} are not finite")
    if any(d != 0.0 for d in D):
        if model != "plumb_bob" or len(D) not in (4, 5):
            raise ValueError(
                f"{where}: distortion model {model!r} with coefficients {list(D)} is not undistorted "
                "by vogjax (plumb_bob is; a rectified depth image has all coefficients 0)"
            )
    return Camera(_frame(msg.header.frame_id), width, height, K, model, D)


def _field(msg: Any, name: str) -> Any:
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())  # ROS 2: k; ROS 1: K


def _frame(name: str) -> str:
    return name.lstrip("/")


def check_stride(stride: int) -> None:
    """Refuse a stride that is not a positive whole number of pixels (ValueError naming it)."""
    if isinstance(stride, (bool, np.bool_)) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride must be a positive whole number of pixels, got {stride!r}")


def check_pixels(width: int, height: int, stride: int, where: str) -> int:
    """The pixels an image of this size gives at `stride`, refused past what a scan holds.

    Parameters
    ----------
    width, height : int
        Image size, pixels.
    stride : int
        Every `stride`-th pixel of every `stride`-th row.
    where : str
        What an error names (flag and topic).

    Returns
    -------
    int
        The pixels taken.

    Raises
    ------
    ValueError
        Naming `where` when more than 2^20 pixels would be taken (raise the stride).
    """
    check_stride(stride)
    taken = -(-height // stride) * -(-width // stride)
    if taken > MAX_BEAMS:  # refused before any array of that size exists
        raise ValueError(
            f"{where}: {width} x {height} pixels give {taken} at stride {stride}, more than the {MAX_BEAMS} "
            "beams a scan may have (raise --stride)"
        )
    return taken


def depth_points(
    msg: Any, camera: Camera, rays: npt.NDArray[np.float64], stride: int, where: str
) -> npt.NDArray[np.float64]:
    """The points of a depth image's strided pixels, NaN where a pixel holds no depth.

    Parameters
    ----------
    msg : sensor_msgs/msg/Image
        A depth image (16UC1 millimetres or 32FC1 metres, either byte order).
    camera : Camera
        Its camera.
    rays : (M, 3) ndarray of float64
        ``camera.rays(stride)``.
    stride : int
        Every `stride`-th pixel of every `stride`-th row.
    where : str
        What an error names (flag and topic).

    Returns
    -------
    (M, 3) ndarray of float64
        x, y, z in the image's frame, metres; rows of NaN for pixels without a depth (0, NaN,
        infinite or negative).

    Raises
    ------
    ValueError
        Naming `where` when the encoding is not a depth encoding, the image's size differs from
        its CameraInfo's, more than 2^20 pixels would be taken (checked before converting), the
        rows are shorter than the image says, or the data are not rows x step bytes.
    """
    encoding = str(msg.encoding)
    if encoding not in ENCODINGS:
        raise ValueError(
            f"{where}: Image encoding {encoding!r} is no depth encoding (16UC1 in mm or 32FC1 in m are read)"
        )
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if (width, height) != (camera.width, camera.height):
        raise ValueError(
            f"{where}: an image of {width} x {height} pixels, but its CameraInfo says {camera.width} x {camera.height}"
        )
    check_pixels(width, height, stride, where)
    sample, scale = ENCODINGS[encoding]
    size = np.dtype(sample).itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < width * size or len(data) != height * step:  # sensor_msgs/Image: data holds step * height
        raise ValueError(
            f"{where}: Image is malformed: {height} x {width} pixels of {encoding}, rows of {step} bytes, "
            f"{len(data)} bytes of data (not {height} x {step})"
        )
    order = ">" if msg.is_bigendian else "<"
    rows = np.ascontiguousarray(data[: height * step].reshape(height, step)[::stride, : width * size])
    depth = rows.view(order + sample)[:, ::stride].reshape(-1).astype(np.float64) * scale
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth > 0)
    return np.where(valid[:, None], rays * depth[:, None], np.nan)
