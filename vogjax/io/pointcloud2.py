"""The fields of a sensor_msgs/PointCloud2, read by name and checked before NumPy sees them.

A cloud carries x, y, z and, from most lidar drivers, more: a per-point time (`time` from
Velodyne's driver, `t` from Ouster's, `timestamp` from Livox's and Hesai's), an `intensity`, a
`ring` (the laser that fired), and fields vogjax has no use for (`reflectivity`, `ambient`,
`range`, padding). `read_cloud` reads the ones it uses, reports what it did with every field,
and refuses a layout whose used fields share bytes, overlap the point's end, repeat a used
name, or carry a type the role cannot take.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt

from vogjax.config.sensing import MAX_BEAMS

# sensor_msgs/PointField datatypes: INT8 .. FLOAT64
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
TYPE_NAMES = {1: "int8", 2: "uint8", 3: "int16", 4: "uint16", 5: "int32", 6: "uint32", 7: "float32", 8: "float64"}
TIME_FIELDS = ("time", "t", "timestamp")  # Velodyne, Ouster, Livox/Hesai/Robosense; the first present is used
INTENSITY_FIELD = "intensity"
RING_FIELD = "ring"
_INTEGERS = (1, 2, 3, 4, 5, 6)


@dataclasses.dataclass(frozen=True)
class Cloud:
    """The fields of one PointCloud2 that vogjax uses, every point (invalid ones included).

    Attributes
    ----------
    points : (N, 3) ndarray of float64
        x, y, z in the cloud's frame, metres (NaN where the driver wrote NaN).
    time : (N,) ndarray or None
        The per-point time field as stored (its own dtype, native byte order); None when the
        cloud has none or it was not asked for.
    time_field : str or None
        Its name (`time`, `t` or `timestamp`).
    time_datatype : int or None
        Its PointField datatype (6: uint32, 7: float32, 8: float64, ...).
    intensity : (N,) ndarray of float64 or None
        The `intensity` field, any numeric type, as float64.
    ring : (N,) ndarray of int64 or None
        The `ring` field (an integer type).
    fields : dict of str to dict
        Every field of the cloud by name: its ``type`` and its ``use`` ("position",
        "point time", "intensity", "ring" or "ignored", with the reason where one applies).
    """

    points: npt.NDArray[np.float64]
    time: npt.NDArray[Any] | None
    time_field: str | None
    time_datatype: int | None
    intensity: npt.NDArray[np.float64] | None
    ring: npt.NDArray[np.int64] | None
    fields: dict[str, dict[str, str]]


def read_cloud(msg: Any, where: str, use_time: bool = True) -> Cloud:
    """Read a PointCloud2's x, y, z, per-point time, intensity and ring.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        The message, as rosbags deserialises it.
    where : str
        What an error names (the flag and topic, e.g. "--points topic '/velodyne_points'").
    use_time : bool, optional
        Whether to read the per-point time field (False: it is reported as ignored, the
        importer's --no-deskew).

    Returns
    -------
    Cloud
        Its used fields for every point, and what was done with each field.

    Raises
    ------
    ValueError
        Naming `where` when x, y or z is missing, a used field is named twice, a field has a
        type its role cannot take or more than one element, two used fields share bytes, a
        field reaches past the point's end, the rows are shorter than the layout says, the
        data are not rows x row_step bytes, or the cloud holds more than 2^20 points (checked
        before any point is converted).
    """
    where = f"{where}: PointCloud2"
    names = [f.name for f in msg.fields]
    by_name: dict[str, Any] = {}
    for field in msg.fields:
        by_name.setdefault(field.name, field)
    used = ("x", "y", "z", *TIME_FIELDS, INTENSITY_FIELD, RING_FIELD)
    repeated = sorted(n for n in used if names.count(n) > 1)
    if repeated:
        raise ValueError(f"{where} has field {repeated[0]} twice")
    missing = [n for n in "xyz" if n not in by_name]
    if missing:
        raise ValueError(f"{where} has no field {', '.join(missing)} (fields: {', '.join(by_name) or 'none'})")
    time_name = next((n for n in TIME_FIELDS if n in by_name), None)
    roles = {"x": "position", "y": "position", "z": "position"}
    if time_name is not None and use_time:
        roles[time_name] = "point time"
    if INTENSITY_FIELD in by_name:
        roles[INTENSITY_FIELD] = "intensity"
    if RING_FIELD in by_name:
        roles[RING_FIELD] = "ring"
    order = ">" if msg.is_bigendian else "<"
    step = int(msg.point_step)
    formats, offsets = [], []
    for name, role in roles.items():
        field = by_name[name]
        kind = int(field.datatype)
        allowed = (7, 8) if role == "position" else _INTEGERS if role == "ring" else tuple(DATATYPES)
        if kind not in allowed or int(field.count) not in (0, 1):
            wanted = {"position": "one float32 or float64", "ring": "one integer"}.get(role, "one number")
            raise ValueError(f"{where} field {name} must be {wanted}, got datatype {kind} x {field.count}")
        formats.append(order + DATATYPES[kind])
        offsets.append(int(field.offset))
    width, height, row_step = int(msg.width), int(msg.height), int(msg.row_step)
    if width * height > MAX_BEAMS:  # a run holds no more beams per scan; refused before converting
        raise ValueError(f"{where} holds {height} x {width} points, more than the {MAX_BEAMS} beams a scan may have")
    data = msg.data
    data = np.frombuffer(data, np.uint8) if isinstance(data, (bytes, bytearray)) else np.asarray(data, np.uint8)
    spans = sorted((o, o + np.dtype(f).itemsize, n) for o, f, n in zip(offsets, formats, roles))
    overlap = next(((a[2], b[2]) for a, b in zip(spans, spans[1:]) if b[0] < a[1]), None)
    if overlap is not None:  # one field's bytes read as another's: a silent wrong value
        raise ValueError(f"{where} is malformed: fields {overlap[0]} and {overlap[1]} share bytes")
    if (
        step <= 0
        or any(o < 0 or o + np.dtype(f).itemsize > step for o, f in zip(offsets, formats))
        or row_step < width * step
        or len(data) != height * row_step  # sensor_msgs/PointCloud2: data holds row_step * height
    ):
        layout = ", ".join(f"{n} at byte {o}" for n, o in zip(roles, offsets))
        raise ValueError(
            f"{where} is malformed: {height} x {width} points of {step} bytes, rows of {row_step} "
            f"bytes, fields {layout}, {len(data)} bytes of data (not {height} x {row_step})"
        )
    dtype = np.dtype({"names": list(roles), "formats": formats, "offsets": offsets, "itemsize": step})
    rows = data[: height * row_step].reshape(height, row_step)[:, : width * step]
    values = np.ascontiguousarray(rows).view(dtype).reshape(-1)
    report = {}
    for field in msg.fields:
        if field.name in report:
            continue
        kind = TYPE_NAMES.get(int(field.datatype), f"datatype {field.datatype}")
        use = roles.get(field.name)
        if use is None:
            use = "ignored"
            if field.name in TIME_FIELDS:
                use = "ignored (deskewing off)" if not use_time else f"ignored (time field {time_name} used)"
        report[field.name] = {"type": kind, "use": use}

    def native(name: str) -> np.ndarray:
        column = values[name]
        return column.astype(column.dtype.newbyteorder("="))

    use_t = time_name is not None and use_time
    return Cloud(
        points=np.stack([values[n].astype(np.float64) for n in "xyz"], axis=1),
        time=native(time_name) if use_t else None,
        time_field=time_name if use_t else None,
        time_datatype=int(by_name[time_name].datatype) if use_t else None,
        intensity=values[INTENSITY_FIELD].astype(np.float64) if INTENSITY_FIELD in roles else None,
        ring=values[RING_FIELD].astype(np.int64) if RING_FIELD in roles else None,
        fields=report,
    )
