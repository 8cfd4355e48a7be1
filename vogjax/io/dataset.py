"""Simulated (or recorded) runs: one HDF5 file per run, chunked and appendable.

Per scan: time_s, pose_truth and pose_nav (4,4, T_world_vehicle), sonar_origin (3,) and
sonar_directions (B,3) in the vehicle frame, ranges (B,) metres (NaN: no return) and no_return
(B,). File attributes: format, format_version, scene, seed, sensor model, navigation noise,
vogjax version. Published atomically on close (`vogjax.io.atomic`): a run is whole or absent.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np

from vogjax.io.atomic import AtomicPath
from vogjax.sensors.base import world_rays

FORMAT = "vogjax-run"
FORMAT_VERSION = 1
_FIELDS = {  # name: (shape after the scan axis given beams B, dtype)
    "time_s": (lambda b: (), np.float64),
    "pose_truth": (lambda b: (4, 4), np.float64),
    "pose_nav": (lambda b: (4, 4), np.float64),
    "sonar_origin": (lambda b: (3,), np.float32),
    "sonar_directions": (lambda b: (b, 3), np.float32),
    "ranges": (lambda b: (b,), np.float32),
    "no_return": (lambda b: (b,), np.bool_),
}


@dataclasses.dataclass(frozen=True)
class ScanBatch:
    """Consecutive scans: each field as in the file, with a leading scan axis."""

    first: int
    time_s: np.ndarray
    pose_truth: np.ndarray
    pose_nav: np.ndarray
    sonar_origin: np.ndarray
    sonar_directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)

    def rows(self, lo: int, hi: int) -> "ScanBatch":
        """Scans lo to hi of this batch."""
        fields = {f.name: getattr(self, f.name)[lo:hi] for f in dataclasses.fields(self) if f.name != "first"}
        return ScanBatch(self.first + lo, **fields)

    def world(self, poses: np.ndarray, max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Sonar origins (S,3) and beam endpoints (S,B,3) in the world, at `poses` (S,4,4).
        Beams without a return end past max_range_m (free space up to it, no hit)."""
        return world_rays(poses, self.sonar_origin, self.sonar_directions, self.ranges, self.no_return,
                          max_range_m)


class DatasetWriter:
    """Append scans to a new run file; `close()` (or the `with` block) publishes it."""

    def __init__(self, path, beams: int, metadata: dict):
        self.path = Path(path)
        self._publication = AtomicPath(self.path)
        self._file = h5py.File(self._publication.temporary, "w")
        self._file.attrs["format"] = FORMAT
        self._file.attrs["format_version"] = FORMAT_VERSION
        self._file.attrs["metadata"] = json.dumps(metadata)
        for name, (shape, dtype) in _FIELDS.items():
            tail = shape(beams)
            self._file.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail), dtype=dtype,
                                      chunks=(256, *tail), compression="lzf")

    def append(self, **fields) -> None:
        missing = set(_FIELDS) - set(fields)
        if missing:
            raise ValueError(f"fields missing: {', '.join(sorted(missing))}")
        count = len(fields["time_s"])
        for name in _FIELDS:
            data = self._file[name]
            data.resize(data.shape[0] + count, axis=0)
            data[-count:] = fields[name]

    def close(self) -> None:
        if self._file:
            self._file.close()
            self._file = None
            self._publication.commit()

    def abort(self) -> None:
        if self._file:
            self._file.close()
            self._file = None
        self._publication.abort()

    def __enter__(self):
        return self

    def __exit__(self, kind, error, trace):
        self.abort() if kind else self.close()


class Dataset:
    """A run file opened for reading: `len(ds)` scans, `ds.metadata`, `ds.batches(size)`."""

    def __init__(self, path):
        self.path = Path(path)
        where = f"path {str(self.path)!r}"
        if not self.path.is_file():
            raise ValueError(f"{where} does not exist")
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as error:
            raise ValueError(f"{where} is not a readable HDF5 run file (truncated or corrupt?): {error}") from None
        try:
            attrs = self._file.attrs
            if attrs.get("format") != FORMAT:
                raise ValueError(f"{where} is not a vogjax run file")
            version = int(attrs["format_version"])
            if version > FORMAT_VERSION:
                raise ValueError(f"{where} has run format version {version}; this vogjax reads up to "
                                 f"{FORMAT_VERSION}: upgrade vogjax")
            self.metadata = json.loads(attrs["metadata"])
            lengths = {name: self._file[name].shape[0] for name in _FIELDS}
        except (KeyError, TypeError, json.JSONDecodeError) as error:
            self._file.close()
            raise ValueError(f"{where} is damaged: {error}") from None
        except ValueError:
            self._file.close()
            raise
        if len(set(lengths.values())) != 1:
            self._file.close()
            raise ValueError(f"{where} is damaged: fields hold different numbers of scans {lengths}")
        self._length = lengths["time_s"]

    def __len__(self) -> int:
        return self._length

    def read(self, first: int, last: int) -> ScanBatch:
        try:
            return ScanBatch(first, **{name: self._file[name][first:last] for name in _FIELDS})
        except OSError as error:  # a chunk that cannot be read or decompressed
            raise ValueError(f"path {str(self.path)!r} is damaged: {error}") from None

    def batches(self, size: int = 200):
        """ScanBatch after ScanBatch of `size` scans (streamed, not loaded whole)."""
        if size < 1:
            raise ValueError(f"size must be positive, got {size!r}")
        for first in range(0, len(self), size):
            yield self.read(first, min(first + size, len(self)))

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
