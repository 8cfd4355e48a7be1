"""Argument checks shared by the public API. Each raises ValueError naming the argument."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vogjax.config.schema import finite_real


def real_array(name: str, value: npt.ArrayLike, dtype: npt.DTypeLike = np.float64) -> npt.NDArray:
    """An array of real numbers (integers or floats), converted to `dtype`.

    Booleans, complex numbers, text and ragged lists are refused: NumPy would quietly convert
    them or refuse them naming nothing.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : array_like
        The values, of any shape.
    dtype : dtype_like, optional
        The dtype of the result (default float64).

    Returns
    -------
    ndarray
        `value` as an array of `dtype` (no copy when it is one already).

    Raises
    ------
    ValueError
        Naming `name`, if `value` cannot be read as an array or does not hold real numbers.
    """
    try:
        array = np.asarray(value)
    except Exception as error:  # ragged lists, jax/torch conversion errors
        raise ValueError(f"{name} could not be read as an array: {error}") from None
    if array.dtype.kind not in "fiu" or array.dtype == np.bool_:
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    return array.astype(dtype, copy=False)


def float_array(
    name: str, value: npt.ArrayLike, shape: tuple[int, ...], dtype: npt.DTypeLike = np.float32
) -> npt.NDArray[np.floating]:
    """A finite floating array of the given shape, converted to `dtype`.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : array_like
        Real numbers.
    shape : tuple of int
        The shape required; -1 in an axis: any length.
    dtype : dtype_like, optional
        The floating dtype of the result (default float32; values beyond its range become
        infinite, which key-range checks refuse).

    Returns
    -------
    ndarray
        A C-contiguous array of `dtype`.

    Raises
    ------
    ValueError
        Naming `name`: not real numbers, the wrong shape, or NaN or infinite values.
    """
    array = np.asarray(real_array(name, value, np.float64) if not isinstance(value, np.ndarray) else value)
    if array.dtype.kind not in "fiu" or array.dtype == np.bool_:
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if array.ndim != len(shape) or any(s not in (-1, a) for s, a in zip(shape, array.shape)):
        wanted = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {wanted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")
    with np.errstate(over="ignore"):  # beyond float32: inf, refused by key-range checks, unknown to look-ups
        return np.ascontiguousarray(array, dtype=dtype)


def positive_number(name: str, value: float) -> float:
    """A positive finite real number (a bool is not one), as a float.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : float
        The number.

    Returns
    -------
    float
        `value`.

    Raises
    ------
    ValueError
        Naming `name`, if `value` is not a positive finite real number.
    """
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not (finite_real(value) and value > 0)
    ):
        raise ValueError(f"{name} must be positive and finite (a real number), got {value!r}")
    return float(value)


def positive_range(name: str, value: float | npt.ArrayLike, count: int) -> npt.NDArray[np.float64]:
    """A positive finite range, one for every ray or one per ray.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : float or (count,) array_like of float
        The range, metres.
    count : int
        The number of rays.

    Returns
    -------
    (count,) ndarray of float64
        The range of each ray.

    Raises
    ------
    ValueError
        Naming `name`: not positive and finite real numbers, or not one per ray.
    """
    if np.isscalar(value):
        return np.full(count, positive_number(name, value), dtype=np.float64)
    array = float_array(name, value, (count,), np.float64)
    if np.any(array <= 0):
        raise ValueError(f"{name} must be positive")
    return array


def index_array(name: str, value: npt.ArrayLike, count: int, upper: int) -> npt.NDArray[np.int32]:
    """Integers in [0, upper), one per element, as int32.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : (count,) array_like of int
        The indices (an empty list counts as integers).
    count : int
        The number of elements required.
    upper : int
        One past the largest index allowed.

    Returns
    -------
    (count,) ndarray of int32
        The indices, C-contiguous.

    Raises
    ------
    ValueError
        Naming `name`: not integers, not `count` of them, or outside [0, upper).
    """
    try:
        array = np.asarray(value)
    except Exception as error:  # ragged lists
        raise ValueError(f"{name} could not be read as an array: {error}") from None
    if array.dtype.kind not in "iu" and not (array.size == 0 and array.dtype.kind == "f"):  # [] reads as float
        raise ValueError(f"{name} must hold integers, got dtype {array.dtype}")
    if array.shape != (count,):
        raise ValueError(f"{name} must have shape ({count},), got {array.shape}")
    if count and (array.min() < 0 or array.max() >= upper):
        raise ValueError(f"{name} values must lie in [0, {upper})")
    return np.ascontiguousarray(array, dtype=np.int32)


def within_key_range(name: str, array: npt.NDArray, voxel_size: float, limit: int) -> None:
    """Check that coordinates map to voxel keys the block table can pack.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    array : ndarray
        Coordinates, metres, of any shape.
    voxel_size : float
        The voxel edge, metres.
    limit : int
        The largest voxel key magnitude the table packs (`hashing.VOXEL_KEY_LIMIT`); keys must
        stay 2 below it.

    Raises
    ------
    ValueError
        Naming `name`, if a coordinate lies (limit - 2) voxels or farther from the origin on
        an axis (NaN is not checked here).
    """
    if not array.size:
        return
    if array.dtype.kind == "f":  # |array|.max() without a temporary (NaN propagates alike)
        extent = np.maximum(array.max(), -array.min())
    else:
        extent = np.abs(array).max()
    if extent / voxel_size >= limit - 2:
        raise ValueError(
            f"{name} lies too far from the origin for voxel size {voxel_size} m "
            f"(at most {(limit - 2) * voxel_size:.0f} m per axis)"
        )
