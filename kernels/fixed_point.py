"""Exact sums of log-odds: an integer number of 2^-24 steps, so adding and removing submaps in
any order gives the same bits (the global map and the virtual map both sum this way)."""

import warp as wp

wp.set_module_options({"enable_backward": False})

FIXED_POINT_SCALE = 16777216.0  # 2^24 steps per unit of log-odds
SCALE = wp.constant(wp.float64(FIXED_POINT_SCALE))
INV_SCALE = wp.constant(wp.float64(1.0 / FIXED_POINT_SCALE))  # a power of two: exact, as dividing


@wp.func
def to_fixed_point(value: wp.float32) -> wp.int64:
    return wp.int64(wp.round(wp.float64(value) * SCALE))


@wp.func
def from_fixed_point(total: wp.int64, count: wp.int32, clamp_min: wp.float32, clamp_max: wp.float32) -> wp.float32:
    """Clamped log-odds of a fixed-point sum; NaN where no submap contributes."""
    if count == 0:
        return wp.nan
    return wp.clamp(wp.float32(wp.float64(total) * INV_SCALE), clamp_min, clamp_max)
