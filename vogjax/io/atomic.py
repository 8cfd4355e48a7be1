"""Atomic publication of files and folders: every writer in vogjax goes through here.

Work happens under a hidden temporary name beside the target (`.NAME.PID.tmp`); `commit`
flushes it to disk (fsync), renames it over the target and syncs the folder, so a reader sees
the old target or the whole new one, never a part. A crash (even kill -9) leaves only the
temporary, and the next write to the same target removes temporaries whose process is gone.

A folder cannot be renamed over a full one. On Linux the two are swapped in one step
(renameat2 with RENAME_EXCHANGE) and the old one, now under the temporary's name, is removed;
elsewhere the old one is moved aside first, and a crash between the two renames is repaired by
the next write (`remove_stale`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any


def as_path(value: Any, name: str = "path") -> Path:
    """A path argument as a Path, refusing anything that is not one.

    Parameters
    ----------
    value : Any
        The argument: a non-empty str or an os.PathLike.
    name : str, optional
        The argument's name, for the error message.

    Returns
    -------
    Path
        `value` as a Path.

    Raises
    ------
    ValueError
        Naming `name` if `value` is not a str or os.PathLike, or is empty.
    """
    if not isinstance(value, (str, os.PathLike)) or str(value) == "":
        raise ValueError(f"{name} must be a file path (str or os.PathLike), got {value!r}")
    return Path(value)


class AtomicPath:
    """A temporary file or folder that becomes `target` on `commit()`.

    The temporary is ``.NAME.PID.tmp`` beside the target. As a context manager it yields the
    temporary's path, commits when the block succeeds and aborts when it raises. Construction
    checks that the target can be published (`check_writable`) and removes stale temporaries
    of it, so a refusal comes before any work.

    Parameters
    ----------
    target : str or os.PathLike
        The file or folder to publish; its folder must exist.
    folder : bool, optional
        Publish a folder (the temporary is created empty) rather than a file.

    Attributes
    ----------
    target : Path
        The path published.
    folder : bool
        Whether it is a folder.
    temporary : Path
        Where to write until `commit`.

    Raises
    ------
    ValueError
        If `target` is not a path, cannot be published (see `check_writable`), or its folder
        does not exist.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out.txt"
    >>> with AtomicPath(target) as temporary:
    ...     _ = temporary.write_text("whole or nothing")
    >>> target.read_text()
    'whole or nothing'
    """

    def __init__(self, target: str | os.PathLike, folder: bool = False):
        self.target = as_path(target)
        self.folder = folder
        check_writable(self.target, folder)
        if not self.target.parent.is_dir():
            raise ValueError(f"{str(self.target)!r}: folder {str(self.target.parent)!r} does not exist")
        remove_stale(self.target)  # this process's own temporary name included
        self.temporary = self.target.parent / f".{self.target.name}.{os.getpid()}.tmp"
        if folder:
            self.temporary.mkdir(mode=0o777)  # the umask applies, as to any new folder

    def commit(self) -> Path:
        """Publish the temporary as the target: fsync, rename over it, fsync the folder.

        On failure the temporary is removed and the error raised.

        Returns
        -------
        Path
            The target.
        """
        try:
            return self._publish()
        except BaseException:
            self.abort()
            raise

    def _publish(self) -> Path:
        if self.folder:
            for item in self.temporary.rglob("*"):
                if item.is_file():
                    _fsync(item)
        else:
            _fsync(self.temporary)
        if self.folder and self.target.exists():
            if _exchange(self.temporary, self.target):
                _fsync_folder(self.target.parent)
                shutil.rmtree(self.temporary, ignore_errors=True)  # the old folder now
                return self.target
            old = self.target.with_name(f".{self.target.name}.{os.getpid()}.old.tmp")
            os.replace(self.target, old)
            os.replace(self.temporary, self.target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self.temporary, self.target)
        _fsync_folder(self.target.parent)
        return self.target

    def abort(self) -> None:
        """Remove the temporary (nothing, once committed)."""
        _remove(self.temporary)

    def __enter__(self) -> Path:
        return self.temporary

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if kind is None:
            self.commit()
        else:
            self.abort()


def check_writable(target: str | os.PathLike, folder: bool = False) -> None:
    """Refuse a target that cannot be published, before any long work.

    The target must not be the wrong kind of thing (a file where a folder goes, or the other
    way round, or a device, pipe or socket), and its nearest existing ancestor must be a folder
    where files can be created (missing folders on the way would be created).

    Parameters
    ----------
    target : str or os.PathLike
        The file or folder to publish.
    folder : bool, optional
        Whether a folder is to be published.

    Raises
    ------
    ValueError
        Naming the target and what is wrong with it.
    """
    target = Path(target)
    if target.exists() and target.is_dir() != folder:
        kind = "a folder" if target.is_dir() else "a file"
        raise ValueError(f"{str(target)!r} is {kind}; cannot replace it")
    if target.exists() and not folder and not target.is_file():  # renaming over it would replace the node
        raise ValueError(f"{str(target)!r} is a device, pipe or socket, not a regular file; cannot replace it")
    ancestor = target.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{str(target)!r}: {str(ancestor)!r} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(f"{str(target)!r}: folder {str(ancestor)!r} is not writable (permission denied)")
    try:  # os.access trusts the permission bits: root passes them on /proc or a read-only mount
        with tempfile.TemporaryFile(dir=ancestor):
            pass
    except OSError as error:
        raise ValueError(f"{str(target)!r}: cannot create files in folder {str(ancestor)!r} ({_why(error)})") from None


_WHY = {
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EROFS: "a read-only file system",
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
}


def _why(error: OSError) -> str:
    """Why a file could not be created in an existing folder, in words."""
    if error.errno in _WHY:
        return _WHY[error.errno]
    # /proc, /sys and the like exist but take no new files (they answer "No such file")
    return f"its file system takes no new files: {error.strerror or error}"


_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)(?P<old>\.old)?\.tmp$")


def remove_stale(target: str | os.PathLike) -> list[Path]:
    """Remove temporaries of `target` left by processes that no longer run.

    A folder is published over an earlier one in two renames (earlier -> `.NAME.PID.old.tmp`,
    new -> NAME); a process killed between them leaves no NAME. The new folder was complete
    (it is moved only once written and synced), so its publication is finished here; without
    it the earlier folder is put back. Leftovers named with this process's own id count as
    stale too: a process publishes one target at a time, so they are from an earlier process
    that had the same id (common in containers).

    Parameters
    ----------
    target : str or os.PathLike
        The published file or folder whose leftovers to remove.

    Returns
    -------
    list of Path
        The temporaries removed.
    """
    target = Path(target)
    removed = []
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return removed
    stale = [(entry, _LEFTOVER.match(entry.name)) for entry in entries]
    stale = [
        (entry, match)
        for entry, match in stale
        if match
        and match["name"] == target.name
        and (int(match["pid"]) == os.getpid() or not _alive(int(match["pid"])))
    ]
    for entry, match in stale:
        if match["old"] and not target.exists():
            new = entry.with_name(f".{target.name}.{match['pid']}.tmp")
            try:
                os.replace(new if new.is_dir() else entry, target)
            except OSError:  # another process repaired it first
                if not target.exists():
                    raise
    for entry, _ in stale:
        if entry.exists() or entry.is_symlink():
            _remove(entry)
            removed.append(entry)
    return removed


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2():
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True).renameat2
    except (OSError, AttributeError, TypeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return function


_RENAMEAT2 = _renameat2()


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step; False where the system or file system cannot."""
    if _RENAMEAT2 is None:
        return False
    if _RENAMEAT2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EXDEV, errno.EPERM):
        return False  # EPERM: a sandbox refusing the call; a real permission error recurs in the fallback
    raise OSError(code, os.strerror(code), str(b))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot sync a folder
    finally:
        os.close(fd)
