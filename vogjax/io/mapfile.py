"""One-file map format: magic, format version, JSON header, npz payload, SHA-256 of it all.

    bytes 0-7    b"VOGJAXMP"
    bytes 8-11   format version, little-endian uint32
    bytes 12-19  header length H, little-endian uint64
    H bytes      UTF-8 JSON: kind, metadata (config, ...), payload size and SHA-256
    then         numpy .npz archive of the arrays (no pickles)
    last 32      SHA-256 of every byte before them (format 2; format 1 checksums the payload
                 only, and still loads)

Files are published atomically (`vogjax.io.atomic`): a reader never sees half a file.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import struct
import zipfile
from os import PathLike

import numpy as np
import numpy.typing as npt

from vogjax.io.atomic import AtomicPath, as_path

MAGIC = b"VOGJAXMP"
FORMAT_VERSION = 2
_DIGEST = 32  # format 2 ends in the SHA-256 of every byte before it: header included
_PREFIX = struct.Struct("<8sIQ")
MAX_HEADER_BYTES = 1 << 26
# the .npy header versions np.savez writes, and their readers
_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def write_map_file(path: str | PathLike, kind: str, metadata: dict, arrays: dict[str, npt.ArrayLike]) -> None:
    """Write a map file: header, arrays and checksum, published atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced if it exists; a reader sees the old file or the whole new
        one).
    kind : str
        The map class the file holds ("VoxelMap", "GlobalMap", "ConfidenceMap", ...);
        `read_map_file` refuses a file of another kind.
    metadata : dict
        JSON-serialisable metadata (the map's config and the like), stored in the header.
    arrays : dict of str to array_like
        The arrays, stored as an uncompressed .npz payload (no pickles).

    Raises
    ------
    ValueError
        If `path` is not a path, its folder does not exist or is not writable, or it names a
        folder, device or pipe.
    """
    path = as_path(path)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    payload = buffer.getvalue()
    header = json.dumps(
        {
            "kind": kind,
            "metadata": metadata,
            "payload_bytes": len(payload),
            "payload_sha256": hashlib.sha256(payload).hexdigest(),
        }
    ).encode()
    contents = _PREFIX.pack(MAGIC, FORMAT_VERSION, len(header)) + header + payload
    with AtomicPath(path) as temporary, open(temporary, "wb") as f:
        f.write(contents)
        f.write(hashlib.sha256(contents).digest())


def map_kind(path: str | PathLike) -> str:
    """The kind a map file's header names, reading only the header.

    The whole file is checked when it is loaded (`read_map_file`).

    Parameters
    ----------
    path : str or os.PathLike
        A map file.

    Returns
    -------
    str
        The kind: "VoxelMap", "GlobalMap", "ConfidenceMap", ...

    Raises
    ------
    ValueError
        If the file cannot be read, is no vogjax map file or has a damaged header.
    """
    path = as_path(path)
    try:
        with open(path, "rb") as f:
            prefix = f.read(_PREFIX.size)
            if len(prefix) < _PREFIX.size:
                raise ValueError(f"path {str(path)!r} is truncated or not a vogjax map file")
            magic, _, header_bytes = _PREFIX.unpack(prefix)
            if magic != MAGIC:
                raise ValueError(f"path {str(path)!r} is not a vogjax map file")
            header = f.read(min(header_bytes, MAX_HEADER_BYTES))
    except OSError as error:
        raise ValueError(f"path {str(path)!r} cannot be read: {error.strerror}") from None
    try:
        kind = json.loads(header)["kind"]
    except (ValueError, KeyError, TypeError, RecursionError):
        raise ValueError(f"path {str(path)!r} has a damaged header") from None
    return str(kind)


def read_map_file(path: str | PathLike, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """Read a map file of the given kind, checking all of it first.

    The checksum, header and payload are verified, and each array's declared size against the
    bytes it holds before anything is allocated; format versions 1 and 2 are read.

    Parameters
    ----------
    path : str or os.PathLike
        A map file written by `write_map_file`.
    kind : str
        The kind the file must hold ("VoxelMap", ...).

    Returns
    -------
    metadata : dict
        The header's metadata.
    arrays : dict of str to ndarray
        The arrays by name.

    Raises
    ------
    ValueError
        Naming the file if it cannot be read, is no vogjax map file, has a format version this
        vogjax does not read, is truncated, corrupt (checksum mismatch) or has trailing data, has
        a damaged header or an unreadable payload, or holds another kind of map.
    """
    path = as_path(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ValueError(f"path {str(path)!r} cannot be read: {error.strerror}") from None
    if len(data) < _PREFIX.size:
        raise ValueError(f"path {str(path)!r} is truncated or not a vogjax map file")
    magic, version, header_bytes = _PREFIX.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"path {str(path)!r} is not a vogjax map file")
    if version < 1:
        raise ValueError(f"path {str(path)!r} has map format version {version}, which no vogjax wrote")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"path {str(path)!r} has map format version {version}; this vogjax reads "
            f"up to version {FORMAT_VERSION}: upgrade vogjax"
        )
    if version >= 2:  # the whole file is checksummed: a damaged header is caught too
        if len(data) < _PREFIX.size + _DIGEST or hashlib.sha256(data[:-_DIGEST]).digest() != data[-_DIGEST:]:
            raise ValueError(f"path {str(path)!r} is corrupt, truncated or has trailing data: checksum mismatch")
        data = data[:-_DIGEST]
    end_of_header = _PREFIX.size + header_bytes
    if end_of_header > len(data):
        raise ValueError(f"path {str(path)!r} is truncated (header incomplete)")
    try:
        header = json.loads(data[_PREFIX.size : end_of_header])
        payload_bytes = header["payload_bytes"]
        if isinstance(payload_bytes, bool) or not isinstance(payload_bytes, int):  # 1e400 is no count
            raise TypeError("payload_bytes is not an integer")
        checksum = header["payload_sha256"]
        metadata = header["metadata"]
        if not isinstance(metadata, dict):
            raise TypeError("metadata is not an object")
    except (ValueError, KeyError, TypeError, RecursionError):
        raise ValueError(f"path {str(path)!r} has a damaged header") from None
    payload = data[end_of_header:]
    if len(payload) != payload_bytes:
        raise ValueError(
            f"path {str(path)!r} is truncated or has trailing data "
            f"({len(payload)} payload bytes, expected {payload_bytes})"
        )
    if hashlib.sha256(payload).hexdigest() != checksum:
        raise ValueError(f"path {str(path)!r} is corrupt: checksum mismatch")
    if header.get("kind") != kind:
        raise ValueError(f"path {str(path)!r} holds a {header.get('kind')!r}, not a {kind!r}")
    try:
        _check_members(payload)
        with np.load(io.BytesIO(payload), allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (ValueError, OSError, EOFError, RuntimeError, NotImplementedError, zipfile.BadZipFile) as error:
        # zipfile's own refusals (an encrypted member, an unsupported feature) included
        raise ValueError(f"path {str(path)!r} has an unreadable payload: {error}") from None
    return metadata, arrays


def _check_members(payload: bytes) -> None:
    """Each array of the payload must hold the bytes its header promises, checked before
    anything is allocated: a header may declare any shape (np.load would allocate it first)."""
    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        for info in archive.infolist():
            if info.compress_type != zipfile.ZIP_STORED:  # np.savez stores; a compressed size proves nothing
                raise ValueError(f"array {info.filename!r} is compressed")
            if info.flag_bits & 0x1:
                raise ValueError(f"array {info.filename!r} is encrypted")
            # the sizes are the archive's own word: a stored member's bytes must be in the payload
            if info.file_size != info.compress_size or info.header_offset + info.compress_size > len(payload):
                raise ValueError(f"array {info.filename!r} claims {info.file_size} bytes the payload does not hold")
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                if version not in _NPY_HEADERS:
                    raise ValueError(f"array {info.filename!r} has .npy format version {version}")
                shape, _, dtype = _NPY_HEADERS[version](member)
                needed = math.prod(shape) * dtype.itemsize
                if needed > info.file_size - member.tell():
                    raise ValueError(
                        f"array {info.filename!r} declares shape {shape} of {dtype}, "
                        f"more than its {info.file_size} bytes"
                    )
