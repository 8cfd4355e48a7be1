"""Recorded runs: one HDF5 file per run, chunked and appendable.

Per scan: time_s, pose_nav and (when the run has ground truth) pose_truth (4,4,
T_world_vehicle), sonar_origin (3,) and sonar_directions (B,3) in the vehicle frame (any range
sensor's origin and beams, see `vogjax.sensors`), ranges (B,) metres (NaN: no return or an
invalid beam), no_return (B,) and invalid (B,): a beam without a return saw water up to the
sensor's range; an invalid one (its surface within the sensor's blind distance) saw nothing,
and no map clears free space along it. File attributes: format, format_version, has_truth,
metadata (JSON: scene, seed, sensor, navigation noise, vogjax version, ...).

Integrity: every chunk carries HDF5's Fletcher-32 checksum (format 2 on; a damaged chunk
cannot be read back), a chunk HDF5 cannot find reads as NaN (the fill value), the metadata
carries its SHA-256, and every batch is checked for physical sense as it is written and as it
is read (finite times that increase, rigid poses, unit beam directions, ranges in [0, 10 km]
with NaN exactly where no_return or invalid is set, never both). Runs of format 1 (no
checksums, always with ground truth) and format 2 (no `invalid` field: simulators then
reported a beam within the blind distance as "no return") still load, with no beam invalid,
and are checked the same way. A file is published atomically on close
(`vogjax.io.atomic`): a run is whole or absent.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import h5py
import numpy as np

from vogjax.config.sensing import MAX_BEAMS
from vogjax.geometry import RIGID_TOLERANCE
from vogjax.io.atomic import AtomicPath
from vogjax.sensors.base import mapped_beams, world_rays

FORMAT = "vogjax-run"
FORMAT_VERSION = 3
INVALID_SINCE = 3  # the first format with the `invalid` field
MAX_RANGE_M = 10_000.0  # no range sensor reaches farther; larger values are damage
_FIELDS = {  # name: (shape after the scan axis given beams B, dtype)
    "time_s": (lambda b: (), np.float64),
    "pose_truth": (lambda b: (4, 4), np.float64),
    "pose_nav": (lambda b: (4, 4), np.float64),
    "sonar_origin": (lambda b: (3,), np.float32),
    "sonar_directions": (lambda b: (b, 3), np.float32),
    "ranges": (lambda b: (b,), np.float32),
    "no_return": (lambda b: (b,), np.bool_),
    "invalid": (lambda b: (b,), np.bool_),
}


@dataclasses.dataclass(frozen=True)
class ScanBatch:
    """Consecutive scans: each field as in the file, with a leading scan axis (pose_truth None
    when the run has no ground truth; invalid, when not given, no beam invalid)."""

    first: int
    time_s: np.ndarray
    pose_truth: np.ndarray | None
    pose_nav: np.ndarray
    sonar_origin: np.ndarray
    sonar_directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray
    invalid: np.ndarray | None = None

    def __post_init__(self):
        if self.invalid is None and np.ndim(self.no_return) == 2:  # else check_scans refuses the batch
            object.__setattr__(self, "invalid", np.zeros(np.shape(self.no_return), np.bool_))

    def __len__(self) -> int:
        return len(self.time_s)

    def rows(self, lo: int, hi: int) -> ScanBatch:
        """Scans lo to hi of this batch."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "first"}
        return ScanBatch(self.first + lo, **{k: None if v is None else v[lo:hi] for k, v in fields.items()})

    @staticmethod
    def concatenate(batches: list) -> ScanBatch:
        """Consecutive batches as one (the first scan index of the first)."""
        names = [f.name for f in dataclasses.fields(ScanBatch) if f.name != "first"]
        fields = {
            name: (None if getattr(batches[0], name) is None else np.concatenate([getattr(b, name) for b in batches]))
            for name in names
        }
        return ScanBatch(batches[0].first, **fields)

    def world(self, poses: np.ndarray, max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Sensor origins (S,3) and beam endpoints (S,B,3) in the world, at `poses` (S,4,4).
        Beams without a return end past max_range_m (free space up to it, no hit); invalid
        beams end at NaN (`vogjax.sensors.world_rays`)."""
        return world_rays(
            poses, self.sonar_origin, self.sonar_directions, self.ranges, self.no_return, max_range_m, self.invalid
        )

    def beams(self, poses: np.ndarray, max_range_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What a map integrates of these scans at `poses`.

        Parameters
        ----------
        poses : numpy.ndarray, (S, 4, 4) float
            T_world_vehicle of each scan.
        max_range_m : float
            The reach beams without a return clear free space to.

        Returns
        -------
        origins : numpy.ndarray, (S, 3) float
        points : numpy.ndarray, (N, 3) float
            Endpoints of every beam but the invalid ones.
        scan_index : numpy.ndarray, (N,) int64
            The scan of each point (``integrate_scans``'s third argument).
        """
        return mapped_beams(*self.world(poses, max_range_m), self.invalid)

    @property
    def returned(self) -> np.ndarray:
        """(S,B) bool: the beams with a return (neither without one nor invalid)."""
        return ~self.no_return & ~self.invalid


def check_scans(fields: dict, beams: int, where: str, after_time_s: float = -np.inf, truth: bool = True) -> None:
    """ValueError naming `where` and the field unless the scans in `fields` make physical
    sense (see the module docstring); `after_time_s`: the time of the scan before them;
    `truth`: whether pose_truth is due (else it must be None)."""
    for name in _FIELDS:
        if (fields.get(name) is None) != (name == "pose_truth" and not truth):
            raise ValueError(f"{where}: {name} is {'missing' if fields.get(name) is None else 'not expected'}")
        if fields.get(name) is not None and (
            np.ndim(fields[name]) == 0 or np.asarray(fields[name]).dtype.kind not in "fiub"
        ):
            raise ValueError(f"{where}: {name} must be an array with a leading scan axis")
    count = len(fields["time_s"])
    for name, (shape, _) in _FIELDS.items():
        if fields.get(name) is None:
            continue
        value = fields[name]
        if np.shape(value) != (count, *shape(beams)):
            raise ValueError(f"{where}: {name} has shape {np.shape(value)}, expected {(count, *shape(beams))}")
    time_s = np.asarray(fields["time_s"], dtype=np.float64)
    if not np.all(np.isfinite(time_s)) or np.any(np.diff(np.r_[after_time_s, time_s]) <= 0):
        raise ValueError(f"{where}: time_s must be finite and strictly increasing")
    for name in ("pose_nav", "pose_truth"):
        if fields.get(name) is None:
            continue
        poses = np.asarray(fields[name], dtype=np.float64)
        if not np.all(np.isfinite(poses)):
            raise ValueError(f"{where}: {name} holds NaN or infinite values")
        rotations = poses[:, :3, :3]
        error = np.abs(rotations @ rotations.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0)
        if (
            error > 1e3 * RIGID_TOLERANCE
            or np.any(np.linalg.det(rotations) < 0)
            or np.any(poses[:, 3] != [0.0, 0.0, 0.0, 1.0])
        ):
            raise ValueError(f"{where}: {name} holds transforms that are not rigid")
    origin = np.asarray(fields["sonar_origin"], dtype=np.float64)
    if not np.all(np.isfinite(origin)) or np.abs(origin).max(initial=0.0) > MAX_RANGE_M:
        raise ValueError(f"{where}: sonar_origin must be finite and within {MAX_RANGE_M:g} m of the vehicle")
    norms = np.linalg.norm(np.asarray(fields["sonar_directions"], dtype=np.float64), axis=-1)
    if not np.all(np.abs(norms - 1.0) < 1e-3):
        raise ValueError(f"{where}: sonar_directions must be unit vectors")
    ranges = np.asarray(fields["ranges"], dtype=np.float64)
    no_return, invalid = np.asarray(fields["no_return"]), np.asarray(fields["invalid"])
    for name, flags in (("no_return", no_return), ("invalid", invalid)):
        if flags.dtype != np.bool_:
            raise ValueError(f"{where}: {name} must be boolean")
    if np.any(no_return & invalid):
        raise ValueError(f"{where}: a beam is both no_return and invalid")
    missing = no_return | invalid
    returned = ranges[~missing]
    if not np.all(np.isnan(ranges[missing])) or not np.all(np.isfinite(returned)):
        raise ValueError(f"{where}: ranges must be NaN exactly where no_return or invalid is set")
    if returned.size and (returned.min() < 0 or returned.max() > MAX_RANGE_M):
        raise ValueError(
            f"{where}: ranges must lie in [0, {MAX_RANGE_M:g}] m, found [{returned.min():.3g}, {returned.max():.3g}]"
        )


class DatasetWriter:
    """Append scans to a new run file; `close()` (or the `with` block) publishes it.

    beams: B, beams per scan; metadata: JSON-able dict; truth: whether scans carry pose_truth.
    """

    def __init__(self, path, beams: int, metadata: dict, truth: bool = True):
        if not (isinstance(beams, (int, np.integer)) and 1 <= beams <= MAX_BEAMS):
            raise ValueError(f"beams must be an integer in [1, {MAX_BEAMS}], got {beams!r}")
        try:
            encoded = json.dumps(metadata, allow_nan=False)
        except (TypeError, ValueError) as error:
            raise ValueError(f"metadata must be JSON-able: {error}") from None
        if not isinstance(metadata, dict):
            raise ValueError("metadata must be a dict")
        self.path = Path(path)
        self.beams = int(beams)
        self.truth = bool(truth)
        self._last_time_s = -np.inf
        self._publication = AtomicPath(self.path)
        self._file = h5py.File(self._publication.temporary, "w")
        self._file.attrs["format"] = FORMAT
        self._file.attrs["format_version"] = FORMAT_VERSION
        self._file.attrs["has_truth"] = self.truth
        self._file.attrs["metadata"] = encoded
        self._file.attrs["metadata_sha256"] = hashlib.sha256(encoded.encode()).hexdigest()
        for name, (shape, dtype) in self._fields().items():
            tail = shape(beams)
            # NaN where HDF5 has no chunk to read (a damaged chunk index): the checks then fail
            fill = np.nan if np.dtype(dtype).kind == "f" else None
            self._file.create_dataset(
                name,
                shape=(0, *tail),
                maxshape=(None, *tail),
                dtype=dtype,
                chunks=(256, *tail),
                compression="lzf",
                fletcher32=True,
                fillvalue=fill,
            )

    def _fields(self) -> dict:
        return {k: v for k, v in _FIELDS.items() if self.truth or k != "pose_truth"}

    def append(self, **fields) -> None:
        """Append scans: every field of the format (pose_truth only when `truth`), each with a
        leading scan axis; `invalid` may be left out when no beam is invalid (a source that
        drops its invalid beams, as `vogjax import` does). Checked first: a ValueError leaves
        the file as it was."""
        if "invalid" not in fields and np.ndim(fields.get("no_return")) == 2:
            fields["invalid"] = np.zeros(np.shape(fields["no_return"]), np.bool_)
        expected = set(self._fields())
        if set(fields) != expected:
            missing, extra = expected - set(fields), set(fields) - expected
            raise ValueError(
                f"fields missing: {', '.join(sorted(missing)) or '-'}; unexpected: {', '.join(sorted(extra)) or '-'}"
            )
        check_scans(fields, self.beams, f"scans for {str(self.path)!r}", self._last_time_s, self.truth)
        count = len(fields["time_s"])
        if count == 0:
            return
        for name in expected:
            data = self._file[name]
            data.resize(data.shape[0] + count, axis=0)
            data[-count:] = fields[name]
        self._last_time_s = float(fields["time_s"][-1])

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
    """A run file opened for reading: `len(ds)` scans, `ds.metadata`, `ds.has_truth`,
    `ds.batches(size)` (each batch checked as it is read), `ds.validate()` (the whole file)."""

    def __init__(self, path):
        self.path = Path(path)
        where = f"path {str(self.path)!r}"
        if not self.path.is_file():
            raise ValueError(f"{where} {'is not a file' if self.path.exists() else 'does not exist'}")
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as error:
            raise ValueError(f"{where} is not a readable HDF5 run file (truncated or corrupt?): {error}") from None
        try:
            attrs = self._file.attrs
            if not _is_text(attrs.get("format"), FORMAT):
                raise ValueError(f"{where} is not a vogjax run file")
            version = attrs["format_version"]
            if not isinstance(version, (int, np.integer)) or isinstance(version, (bool, np.bool_)):
                raise ValueError(f"{where} is damaged: format_version {version!r} is no integer")
            if version < 1:
                raise ValueError(f"{where} is damaged: format_version {version} (no vogjax wrote it)")
            if version > FORMAT_VERSION:
                raise ValueError(
                    f"{where} has run format version {version}; this vogjax reads up to "
                    f"{FORMAT_VERSION}: upgrade vogjax"
                )
            has_truth = attrs.get("has_truth", True)
            if not isinstance(has_truth, (bool, np.bool_)):
                raise ValueError(f"{where} is damaged: has_truth {has_truth!r} is no boolean")
            self.has_truth = bool(has_truth)
            encoded = attrs["metadata"]
            if not isinstance(encoded, str):
                raise ValueError(f"{where} is damaged: its metadata is no text")
            digest = attrs.get("metadata_sha256")
            if digest is not None and digest != hashlib.sha256(encoded.encode()).hexdigest():
                raise ValueError(f"{where} is damaged: its metadata fails its checksum")
            self.metadata = json.loads(encoded)
            if not isinstance(self.metadata, dict):
                raise ValueError(f"{where} is damaged: its metadata is not a JSON object")
            self.format_version = int(version)
            # runs before format 3 hold no `invalid` field: no beam of theirs is invalid
            self._stored = [
                n
                for n in _FIELDS
                if (self.has_truth or n != "pose_truth") and (n != "invalid" or version >= INVALID_SINCE)
            ]
            names = self._stored
            lengths = {name: self._file[name].shape[0] for name in names}
            self.beams = int(self._file["ranges"].shape[1])
            if not 1 <= self.beams <= MAX_BEAMS:  # a small file may declare any shape
                raise ValueError(f"{where} is damaged: {self.beams} beams per scan (at most {MAX_BEAMS})")
            for name in names:
                shape, dtype = _FIELDS[name]
                if self._file[name].shape[1:] != shape(self.beams) or self._file[name].dtype != dtype:
                    raise ValueError(
                        f"{where} is damaged: field {name} has shape {self._file[name].shape} "
                        f"and type {self._file[name].dtype}"
                    )
        except (KeyError, TypeError, IndexError, OSError, json.JSONDecodeError, UnicodeError, RecursionError) as error:
            self._file.close()
            raise ValueError(f"{where} is damaged: {error}") from None
        except ValueError:
            self._file.close()
            raise
        if len(set(lengths.values())) != 1:
            self._file.close()
            raise ValueError(f"{where} is damaged: fields hold different numbers of scans {lengths}")
        self._length = lengths["time_s"]
        self._last_time_s = {}  # first scan of a batch -> time of the scan before it, once read

    def __len__(self) -> int:
        return self._length

    def read(self, first: int, last: int) -> ScanBatch:
        """Scans first to last, checked (ValueError naming the file when damaged)."""
        where = f"path {str(self.path)!r}"
        try:
            fields = {name: (self._file[name][first:last] if name in self._stored else None) for name in _FIELDS}
            if "invalid" not in self._stored:
                fields["invalid"] = np.zeros(fields["no_return"].shape, np.bool_)
        except OSError as error:  # a chunk that cannot be read, decompressed or fails its checksum
            raise ValueError(f"{where} is damaged: {error}") from None
        before = self._last_time_s.get(first, -np.inf)
        check_scans(fields, self.beams, f"{where} is damaged (scans {first}-{last - 1})", before, self.has_truth)
        if last > first:
            self._last_time_s[last] = float(fields["time_s"][-1])
        return ScanBatch(first, **fields)

    def batches(self, size: int = 200):
        """ScanBatch after ScanBatch of `size` scans (streamed, not loaded whole)."""
        if not (isinstance(size, (int, np.integer)) and size >= 1):
            raise ValueError(f"size must be a positive integer, got {size!r}")
        for first in range(0, len(self), size):
            yield self.read(first, min(first + size, len(self)))

    def validate(self, size: int = 2000) -> None:
        """Read and check every scan (a ValueError names the file and the damage)."""
        for _ in self.batches(size):
            pass

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _is_text(value, expected: str) -> bool:
    return isinstance(value, str) and value == expected
