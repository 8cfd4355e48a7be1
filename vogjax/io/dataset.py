"""Recorded runs: one HDF5 file per run, chunked and appendable.

Per scan: time_s, pose_nav and (when the run has ground truth) pose_truth (4,4,
T_world_vehicle), sonar_origin (3,) and sonar_directions (B,3) in the vehicle frame (any range
sensor's origin and beams, see `vogjax.sensors`), ranges (B,) metres (NaN: no return or an
invalid beam), no_return (B,) and invalid (B,): a beam without a return saw water up to the
sensor's range; an invalid one (its surface within the sensor's blind distance) saw nothing,
and no map clears free space along it. Optional per-beam fields, written by sources that have
them (`vogjax import` of a lidar): intensity (B,) float32 (the driver's units) and ring (B,)
uint16 (the laser that fired); a run without them reads them as None, and readers that predate
them ignore them (no format version of their own). File attributes: format, format_version,
has_truth, metadata (JSON: scene, seed, sensor, navigation noise, vogjax version, ...).

Integrity: every chunk carries HDF5's Fletcher-32 checksum (format 2 on; a damaged chunk
cannot be read back), a chunk HDF5 cannot find reads as NaN (the fill value), the metadata
carries its SHA-256, and every batch is checked for physical sense as it is written and as it
is read (finite times that increase, rigid poses, unit beam directions, ranges in [0, 10 km]
with NaN exactly where no_return or invalid is set, never both; intensity finite, ring an
integer). Runs of format 1 (no checksums, always with ground truth) and format 2 (no `invalid`
field: simulators then reported a beam within the blind distance as "no return") still load,
with no beam invalid, and are checked the same way. A file is published atomically on close
(`vogjax.io.atomic`): a run is whole or absent.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Iterator, Sequence
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from vogjax.config.sensing import MAX_BEAMS
from vogjax.geometry import RIGID_TOLERANCE
from vogjax.io.atomic import AtomicPath
from vogjax.sensors.base import mapped_beams, world_rays

FORMAT = "vogjax-run"
FORMAT_VERSION = 3
INVALID_SINCE = 3  # the first format with the `invalid` field
MAX_RANGE_M = 10_000.0  # no range sensor reaches farther; larger values are damage
# Beams a validation step reads: the mapper's batch bound (`config.presets.MAX_BATCH_BEAMS`)
VALIDATE_BEAMS = 1 << 21
# Values per field in one HDF5 chunk: HDF5 reads and writes whole chunks (lzf, Fletcher-32),
# so a scan of a million beams in a chunk of 256 scans cost 3 GB to write or read
CHUNK_VALUES = 1 << 16
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
# per-beam fields a run may hold besides those: name -> (shape after the scan axis, dtype)
OPTIONAL_FIELDS = {
    "intensity": (lambda b: (b,), np.float32),
    "ring": (lambda b: (b,), np.uint16),
}
MAX_RING = 65534  # 65535 is the ring field's fill value: a chunk HDF5 cannot find fails the checks


@dataclasses.dataclass(frozen=True)
class ScanBatch:
    """Consecutive scans of a run: each field as in the file, with a leading scan axis.

    S scans of B beams each; directions and origins are in the vehicle frame.

    Attributes
    ----------
    first : int
        Index in the run of the first scan.
    time_s : (S,) ndarray of float64
        Scan times, seconds, strictly increasing.
    pose_truth : (S, 4, 4) ndarray of float64 or None
        True poses ``T_world_vehicle``; None when the run has no ground truth.
    pose_nav : (S, 4, 4) ndarray of float64
        Navigation (dead-reckoned) poses ``T_world_vehicle``.
    sonar_origin : (S, 3) ndarray of float32
        The sensor's origin in the vehicle frame, metres.
    sonar_directions : (S, B, 3) ndarray of float32
        Unit beam directions in the vehicle frame.
    ranges : (S, B) ndarray of float32
        Ranges, metres; NaN where there was no return or the beam is invalid.
    no_return : (S, B) ndarray of bool
        Where a beam had no return.
    invalid : (S, B) ndarray of bool
        Where a beam is invalid (its surface within the sensor's blind distance: it saw
        nothing); when not given, no beam is.
    intensity : (S, B) ndarray of float32 or None
        Each beam's intensity (the driver's units), where the run holds it.
    ring : (S, B) ndarray of uint16 or None
        The laser (ring) that fired each beam, where the run holds it.
    """

    first: int
    time_s: npt.NDArray[np.float64]
    pose_truth: npt.NDArray[np.float64] | None
    pose_nav: npt.NDArray[np.float64]
    sonar_origin: npt.NDArray[np.float32]
    sonar_directions: npt.NDArray[np.float32]
    ranges: npt.NDArray[np.float32]
    no_return: npt.NDArray[np.bool_]
    invalid: npt.NDArray[np.bool_] | None = None
    intensity: npt.NDArray[np.float32] | None = None
    ring: npt.NDArray[np.uint16] | None = None

    def __post_init__(self) -> None:
        if self.invalid is None and np.ndim(self.no_return) == 2:  # else check_scans refuses the batch
            object.__setattr__(self, "invalid", np.zeros(np.shape(self.no_return), np.bool_))

    def __len__(self) -> int:
        return len(self.time_s)

    def rows(self, lo: int, hi: int) -> ScanBatch:
        """Some scans of this batch.

        Parameters
        ----------
        lo, hi : int
            First and one-past-last scan, counted within this batch.

        Returns
        -------
        ScanBatch
            Scans ``lo:hi`` (views, not copies), with `first` moved by `lo`.
        """
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "first"}
        return ScanBatch(self.first + lo, **{k: None if v is None else v[lo:hi] for k, v in fields.items()})

    @staticmethod
    def concatenate(batches: Sequence[ScanBatch]) -> ScanBatch:
        """Consecutive batches as one.

        Parameters
        ----------
        batches : sequence of ScanBatch
            At least one batch, in order, all with or all without ground truth.

        Returns
        -------
        ScanBatch
            Their scans, with the `first` of the first batch.
        """
        names = [f.name for f in dataclasses.fields(ScanBatch) if f.name != "first"]
        fields = {
            name: (None if getattr(batches[0], name) is None else np.concatenate([getattr(b, name) for b in batches]))
            for name in names
        }
        return ScanBatch(batches[0].first, **fields)

    def world(
        self, poses: npt.NDArray[np.floating], max_range_m: float
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The scans' rays in the world frame, at given vehicle poses.

        Parameters
        ----------
        poses : (S, 4, 4) ndarray of float
            ``T_world_vehicle`` of each scan (`pose_nav`, `pose_truth` or optimised poses).
        max_range_m : float
            The sensor's reach, metres: beams without a return end past it (free space up to
            it, no hit).

        Returns
        -------
        origins : (S, 3) ndarray of float64
            Sensor origins in the world, metres.
        endpoints : (S, B, 3) ndarray of float64
            Beam endpoints in the world, metres; NaN for invalid beams (`vogjax.sensors.world_rays`).
        """
        return world_rays(
            poses, self.sonar_origin, self.sonar_directions, self.ranges, self.no_return, max_range_m, self.invalid
        )

    def beams(
        self, poses: npt.NDArray[np.floating], max_range_m: float
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """What a map integrates of these scans at `poses`.

        Parameters
        ----------
        poses : (S, 4, 4) ndarray of float
            ``T_world_vehicle`` of each scan.
        max_range_m : float
            The reach beams without a return clear free space to, metres.

        Returns
        -------
        origins : (S, 3) ndarray of float64
            Sensor origins in the world, metres.
        points : (N, 3) ndarray of float64
            Endpoints of every beam but the invalid ones.
        scan_index : (N,) ndarray of int64
            The scan of each point (``integrate_scans``'s third argument).
        """
        return mapped_beams(*self.world(poses, max_range_m), self.invalid)

    @property
    def returned(self) -> npt.NDArray[np.bool_]:
        """(S, B) ndarray of bool: the beams with a return (neither without one nor invalid)."""
        return ~self.no_return & ~self.invalid


def check_scans(
    fields: dict[str, Any], beams: int, where: str, after_time_s: float = -np.inf, truth: bool = True
) -> None:
    """Check that scans make physical sense, as they are written and as they are read.

    Times must be finite and strictly increasing, poses rigid, beam directions unit vectors,
    origins within 10 km of the vehicle, and ranges in [0, 10 km] with NaN exactly where
    no_return is set.

    Parameters
    ----------
    fields : dict of str to array_like
        Every field of the format by name (see `ScanBatch`), each with a leading scan axis.
    beams : int
        B, beams per scan.
    where : str
        What the error message names (the file, the scans).
    after_time_s : float, optional
        The time of the scan before them (their times must exceed it).
    truth : bool, optional
        Whether pose_truth is due (else it must be None).

    Raises
    ------
    ValueError
        Naming `where` and the field that is missing, unexpected, of the wrong shape or type,
        or breaks one of the rules above.
    """
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
    directions = np.asarray(fields["sonar_directions"], dtype=np.float64)
    # einsum's sum of squares: np.linalg.norm's temporaries cost a lidar batch ten times as much
    norms = np.sqrt(np.einsum("...i,...i->...", directions, directions))
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
    check_optional_fields(fields, count, beams, where)


def check_optional_fields(fields: dict[str, Any], count: int, beams: int, where: str) -> None:
    """Check the optional per-beam fields that `fields` holds (those that are not None).

    Parameters
    ----------
    fields : dict of str to array_like
        Fields by name; keys of `OPTIONAL_FIELDS` that are absent or None are not checked.
    count : int
        S, the scans the fields hold.
    beams : int
        B, beams per scan.
    where : str
        What the error message names.

    Raises
    ------
    ValueError
        Naming `where` and the field when it is not of shape (S, B), intensity is not a finite
        float, or ring is not an integer in [0, 65534].
    """
    for name in OPTIONAL_FIELDS:
        value = fields.get(name)
        if value is None:
            continue
        value = np.asarray(value)
        if value.shape != (count, beams):
            raise ValueError(f"{where}: {name} has shape {value.shape}, expected {(count, beams)}")
        if name == "intensity" and (value.dtype.kind not in "fiu" or not np.all(np.isfinite(value))):
            raise ValueError(f"{where}: intensity must be finite numbers")
        if name == "ring" and (
            value.dtype.kind not in "iu" or (value.size and (value.min() < 0 or value.max() > MAX_RING))
        ):
            raise ValueError(f"{where}: ring must be integers in [0, {MAX_RING}]")


class DatasetWriter:
    """Append scans to a new run file; `close()` (or the end of the `with` block) publishes it.

    The file is written under a temporary name and published atomically: a run is whole or
    absent. Every chunk carries a Fletcher-32 checksum and the metadata its SHA-256.

    Parameters
    ----------
    path : str or os.PathLike
        The run file (.h5) to write; replaced on publication if it exists.
    beams : int
        B, beams per scan, in [1, 2^20].
    metadata : dict
        JSON-able run metadata (scene, seed, sensor, navigation noise, ...); no NaN.
    truth : bool, optional
        Whether scans carry pose_truth.
    optional : sequence of str, optional
        The optional per-beam fields (keys of `OPTIONAL_FIELDS`: "intensity", "ring") the scans
        carry; `append` then takes them too.

    Attributes
    ----------
    path : Path
        The run file.
    beams : int
        Beams per scan.
    truth : bool
        Whether scans carry pose_truth.
    optional : tuple of str
        The optional per-beam fields written.

    Raises
    ------
    ValueError
        If `beams` is out of range, `metadata` is not a JSON-able dict, `optional` names an
        unknown field, or `path` cannot be written.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> import numpy as np
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "run.h5"
    >>> with DatasetWriter(path, beams=1, metadata={"scene": "none"}, truth=False) as run:
    ...     run.append(time_s=np.array([0.0]), pose_nav=np.eye(4)[None], sonar_origin=np.zeros((1, 3)),
    ...                sonar_directions=np.array([[[1.0, 0, 0]]]), ranges=np.array([[2.0]]),
    ...                no_return=np.array([[False]]))
    >>> len(Dataset(path))
    1
    """

    def __init__(
        self, path: str | PathLike, beams: int, metadata: dict, truth: bool = True, optional: Sequence[str] = ()
    ):
        if not (isinstance(beams, (int, np.integer)) and 1 <= beams <= MAX_BEAMS):
            raise ValueError(f"beams must be an integer in [1, {MAX_BEAMS}], got {beams!r}")
        unknown = sorted(set(optional) - set(OPTIONAL_FIELDS))
        if unknown:
            raise ValueError(f"optional names unknown fields {unknown} (known: {', '.join(OPTIONAL_FIELDS)})")
        encoded = _encoded(metadata)
        self.path = Path(path)
        self.beams = int(beams)
        self.truth = bool(truth)
        self.optional = tuple(n for n in OPTIONAL_FIELDS if n in optional)
        self._last_time_s = -np.inf
        self._publication = AtomicPath(self.path)
        self._file = h5py.File(self._publication.temporary, "w")
        self._file.attrs["format"] = FORMAT
        self._file.attrs["format_version"] = FORMAT_VERSION
        self._file.attrs["has_truth"] = self.truth
        self._write_metadata(encoded)
        for name, (shape, dtype) in self._fields().items():
            tail = shape(beams)
            # NaN where HDF5 has no chunk to read (a damaged chunk index): the checks then fail
            fill = np.nan if np.dtype(dtype).kind == "f" else MAX_RING + 1 if name == "ring" else None
            self._file.create_dataset(
                name,
                shape=(0, *tail),
                maxshape=(None, *tail),
                dtype=dtype,
                chunks=(_chunk_scans(tail), *tail),
                compression="lzf",
                fletcher32=True,
                fillvalue=fill,
            )

    def _fields(self) -> dict:
        chosen = {k: v for k, v in _FIELDS.items() if self.truth or k != "pose_truth"}
        return chosen | {k: OPTIONAL_FIELDS[k] for k in self.optional}

    def _write_metadata(self, encoded: str) -> None:
        self._file.attrs["metadata"] = encoded
        self._file.attrs["metadata_sha256"] = hashlib.sha256(encoded.encode()).hexdigest()

    def set_metadata(self, metadata: dict) -> None:
        """Replace the run's metadata before it is published (what a source learns only at the end).

        Parameters
        ----------
        metadata : dict
            JSON-able run metadata; no NaN.

        Raises
        ------
        ValueError
            If `metadata` is not a JSON-able dict or the file is closed.
        """
        encoded = _encoded(metadata)
        if not self._file:
            raise ValueError(f"the run {str(self.path)!r} is closed")
        self._write_metadata(encoded)

    def append(self, **fields: npt.ArrayLike) -> None:
        """Append scans, checked first (`check_scans`): a ValueError leaves the file as it was.

        Parameters
        ----------
        **fields
            Every field of the format by name (`ScanBatch`'s, pose_truth only when `truth`,
            the optional ones named by `optional`), each with a leading scan axis; times after
            those already written. ``invalid`` may be left out when no beam is invalid (a
            source that drops its invalid beams).

        Raises
        ------
        ValueError
            If a field is missing or unexpected, or the scans do not make physical sense.
        """
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
        """Close the file and publish it at `path` (nothing, once closed)."""
        if self._file:
            self._file.close()
            self._file = None
            self._publication.commit()

    def abort(self) -> None:
        """Close the file and remove it: nothing is published (the `with` block's exit on an error)."""
        if self._file:
            self._file.close()
            self._file = None
        self._publication.abort()

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.abort() if kind else self.close()


class Dataset:
    """A run file opened for reading.

        ``len(ds)`` is its number of scans; `batches` streams them, each batch checked as it is
        read; `validate` checks the whole file. Runs of format 1 and 2 are read, with or without the
    optional per-beam fields. A context manager
        (closes the file on exit).

        Parameters
        ----------
        path : str or os.PathLike
            A run file written by `DatasetWriter`.

        Attributes
        ----------
        path : Path
            The run file.
        metadata : dict
            The run's metadata (scene, seed, sensor, navigation noise, vogjax version, ...).
        has_truth : bool
            Whether scans carry pose_truth.
        beams : int
            Beams per scan.
        optional : tuple of str
            The optional per-beam fields the run holds ("intensity", "ring"); the others read as None.

        Raises
        ------
        ValueError
            Naming the file if it does not exist, is not a readable HDF5 vogjax run file, has a
            format version this vogjax does not read, or is damaged (metadata failing its checksum,
            fields of the wrong shape or type or of different lengths).
    """

    def __init__(self, path: str | PathLike):
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
            self.optional = tuple(n for n in OPTIONAL_FIELDS if n in self._file)
            names = self._stored + list(self.optional)
            for name in names + ["ranges"]:
                if not isinstance(self._file[name], h5py.Dataset):  # a group has no scans
                    raise ValueError(f"{where} is damaged: field {name} is not a dataset")
            lengths = {name: self._file[name].shape[0] for name in names}
            self.beams = int(self._file["ranges"].shape[1])
            if not 1 <= self.beams <= MAX_BEAMS:  # a small file may declare any shape
                raise ValueError(f"{where} is damaged: {self.beams} beams per scan (at most {MAX_BEAMS})")
            for name in names:
                shape, dtype = {**_FIELDS, **OPTIONAL_FIELDS}[name]
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
        """Read some scans, checked as `check_scans` checks.

        Parameters
        ----------
        first, last : int
            First and one-past-last scan index.

        Returns
        -------
        ScanBatch
            Scans ``first:last``.

        Raises
        ------
        ValueError
            Naming the file and the scans if a chunk cannot be read or fails its checksum, or the
            scans do not make physical sense.
        """
        where = f"path {str(self.path)!r}"
        try:
            fields = {name: (self._file[name][first:last] if name in self._stored else None) for name in _FIELDS}
            if "invalid" not in self._stored:
                fields["invalid"] = np.zeros(fields["no_return"].shape, np.bool_)
            fields |= {name: self._file[name][first:last] for name in self.optional}
        except OSError as error:  # a chunk that cannot be read, decompressed or fails its checksum
            raise ValueError(f"{where} is damaged: {error}") from None
        before = self._last_time_s.get(first, -np.inf)
        check_scans(fields, self.beams, f"{where} is damaged (scans {first}-{last - 1})", before, self.has_truth)
        if last > first:
            self._last_time_s[last] = float(fields["time_s"][-1])
        return ScanBatch(first, **fields)

    def batches(self, size: int = 200) -> Iterator[ScanBatch]:
        """Stream the run in batches, each checked as it is read (not loaded whole).

        Parameters
        ----------
        size : int, optional
            Scans per batch (the last may hold fewer).

        Yields
        ------
        ScanBatch
            The next `size` scans.

        Raises
        ------
        ValueError
            If `size` is not a positive integer, or a batch is damaged (see `read`).
        """
        if not (isinstance(size, (int, np.integer)) and size >= 1):
            raise ValueError(f"size must be a positive integer, got {size!r}")
        for first in range(0, len(self), size):
            yield self.read(first, min(first + size, len(self)))

    def validate(self, size: int | None = None) -> None:
        """Read and check every scan.

        Parameters
        ----------
        size : int or None, optional
            Scans read per step (None: up to 2000, and at most VALIDATE_BEAMS beams in all, so
            a lidar run's check holds no more than the mapper's own batches).

        Raises
        ------
        ValueError
            Naming the file and the damage: a scan, or the sensor its metadata describes.
        """
        from vogjax import sensors  # (sensors import this module)

        try:
            sensors.from_metadata(self.metadata)
        except ValueError as error:
            raise ValueError(f"dataset {str(self.path)!r}: {error}") from None
        for _ in self.batches(size or max(1, min(2000, VALIDATE_BEAMS // self.beams))):
            pass

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def __enter__(self) -> Dataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _encoded(metadata: dict) -> str:
    """`metadata` as JSON, or a ValueError."""
    try:
        encoded = json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise ValueError(f"metadata must be JSON-able: {error}") from None
    if not isinstance(metadata, dict):
        raise ValueError("metadata must be a dict")
    return encoded


def _is_text(value, expected: str) -> bool:
    return isinstance(value, str) and value == expected


def _chunk_scans(tail: tuple) -> int:
    """Scans per chunk of a field whose scans hold `tail`-shaped values: 256, fewer where that
    would pass CHUNK_VALUES values."""
    return max(1, min(256, CHUNK_VALUES // max(int(np.prod(tail, dtype=np.int64)), 1)))
