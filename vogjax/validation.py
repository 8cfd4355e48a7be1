"""Argument checks shared by the public API. Each raises ValueError naming the argument."""

from __future__ import annotations

import numpy as np

from vogjax.config.schema import finite_real


def real_array(name: str, value, dtype=np.float64) -> np.ndarray:
    """`value` as an array of real numbers (integers or floats; not booleans, complex numbers,
    text or ragged lists, which NumPy would quietly convert or refuse naming nothing)."""
    try:
        array = np.asarray(value)
    except Exception as error:  # ragged lists, jax/torch conversion errors
        raise ValueError(f"{name} could not be read as an array: {error}") from None
    if array.dtype.kind not in "fiu" or array.dtype == np.bool_:
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    return array.astype(dtype, copy=False)


def float_array(name: str, value, shape: tuple, dtype=np.float32) -> np.ndarray:
    """A finite floating array of the given shape (-1: any length), converted to `dtype`."""
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


def positive_number(name: str, value) -> float:
    """A positive finite real number (a bool is not one), as a float."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not (finite_real(value) and value > 0)
    ):
        raise ValueError(f"{name} must be positive and finite (a real number), got {value!r}")
    return float(value)


def positive_range(name: str, value, count: int) -> np.ndarray:
    """A positive finite range, scalar or one per ray, as a float64 array of length `count`."""
    if np.isscalar(value):
        return np.full(count, positive_number(name, value), dtype=np.float64)
    array = float_array(name, value, (count,), np.float64)
    if np.any(array <= 0):
        raise ValueError(f"{name} must be positive")
    return array


def index_array(name: str, value, count: int, upper: int) -> np.ndarray:
    """Integers in [0, upper), one per element, as int32."""
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


def within_key_range(name: str, array: np.ndarray, voxel_size: float, limit: int) -> None:
    """Coordinates must map to voxel keys the block table can pack."""
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
