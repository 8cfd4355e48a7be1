"""Warp start-up and device choice."""

import functools

import warp as wp


@functools.cache
def init() -> None:
    """Start Warp once, quietly: no banner or per-module load lines (stdout carries results only)."""
    wp.config.log_level = wp.LOG_WARNING
    wp.init()


def resolve(device: "str | wp.Device | None" = None) -> "wp.Device":
    """The Warp device to run on, Warp started first.

    Parameters
    ----------
    device : str or warp.Device or None, optional
        A Warp device or its name ("cpu", "cuda:0", ...); None picks the first CUDA device when
        there is one, else the CPU.

    Returns
    -------
    warp.Device
        The device.

    Raises
    ------
    ValueError
        If `device` is not available (naming it and Warp's reason).
    """
    init()
    if device is None:
        return wp.get_device("cuda:0" if wp.get_cuda_device_count() > 0 else "cpu")
    try:
        return wp.get_device(device)
    except (RuntimeError, ValueError, KeyError) as error:
        raise ValueError(f"device {device!r} is not available: {error}") from None
