"""Where a recording goes — and any other file a command writes (a plot, a parameter dump, a
campaign's results): under a temporary name beside its target, ``NAME.partial``, put in place
by a rename only once it is complete. A reader never takes half a recording for a whole one,
and a target is never replaced unasked.

* :class:`Output` — one file or directory (a rosbag2). An existing target is refused unless
  ``force``; ``NAME.partial`` is held under an ``flock`` for as long as it is written, so a
  second live writer of the same target is refused (:class:`OutputBusy`) instead of writing
  into the same bytes; one left by a writer that died is refused like an existing target (it
  holds what that writer recorded). :meth:`Output.commit` syncs it and renames it into place
  (without replacing anything unless ``force``); :meth:`Output.discard` removes it.
* :class:`DirectoryLock` — one writer at a time of a directory of recordings (a campaign's
  ``--out``), re-entrant within a process.
* :class:`ReservedSpace` — room kept allocated past a file's end (``fallocate`` with
  ``KEEP_SIZE``), so a disk that fills still takes the file's summary.

Errors: :class:`RecordingError` (a recording could not be written or finished), and two
kinds of it said before anything is written: :class:`OutputRefused` (the target exists, is of
the wrong kind, or its directory is missing) and :class:`OutputBusy`.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import os
import shutil
import stat
from pathlib import Path
from types import TracebackType
from typing import IO, Any, ClassVar

from fpgalink.protocol.errors import FpgalinkError

__all__ = [
    "PARTIAL_SUFFIX",
    "DirectoryLock",
    "DiskFull",
    "Output",
    "OutputBusy",
    "OutputRefused",
    "RecordingError",
    "ReservedSpace",
    "check_target",
    "partial_path",
]

#: What a file or directory being written is called until it is complete.
PARTIAL_SUFFIX = ".partial"
#: Room kept allocated past the end of the data for the summary and the next chunk.
RESERVE_BYTES = 512 * 1024


class RecordingError(FpgalinkError):
    """A recording (or another file a command writes) could not be written or finished;
    the message says what is left on disk."""


class OutputRefused(RecordingError):
    """The target cannot be written as asked, said before anything is: it exists and
    replacing it was not asked (``exists``), it is of the wrong kind, or its directory is
    missing."""

    def __init__(self, message: str, path: Path, *, exists: bool = False) -> None:
        super().__init__(message)
        self.path = path
        self.exists = exists


class OutputBusy(RecordingError):
    """Another live process is writing the same target (or directory)."""


class DiskFull(OSError):
    """The disk has no more room: the recording stopped, its file complete up to here."""


def partial_path(target: Path) -> Path:
    """Where ``target`` is written until it is complete."""
    return target.with_name(target.name + PARTIAL_SUFFIX)


def _flock(fd: int) -> bool:
    """Take an exclusive lock on ``fd`` without waiting; ``False`` when another process
    holds it."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on a POSIX system: no locking
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as exc:
        if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL):
            return True  # a filesystem without locks: nothing to refuse with
        raise
    return True


def _open_partial(partial: Path, directory: bool) -> int:
    flags = os.O_CLOEXEC | (os.O_RDONLY | os.O_DIRECTORY if directory else os.O_RDWR)
    return os.open(partial, flags)


def _busy_or_stale(target: Path, partial: Path, directory: bool, force: bool) -> int:
    """A ``partial`` that is there already: :class:`OutputBusy` when a live writer holds it;
    when it was left by one that died, refused without ``force``, else returned opened and
    locked for this writer to take over."""
    fd = _open_partial(partial, directory)
    try:
        if not _flock(fd):
            raise OutputBusy(f"{target}: another process is writing it now ({partial} is "
                             "locked)")
        if not force:
            raise OutputRefused(f"{target}: {partial} is there, left by a recording that did "
                                "not finish (it holds what that one recorded: read it, or "
                                "move it away)", partial, exists=True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def check_target(target: Path, *, force: bool, directory: bool = False) -> Path:
    """Refuse, before any work is done, a target that cannot be written as asked
    (:class:`OutputRefused`, :class:`OutputBusy`); returns the path to write: ``target``, or
    what a symlink there points to (the link stays)."""
    real = target.resolve() if target.is_symlink() else target
    parent = real.parent
    if not parent.is_dir():
        raise OutputRefused(f"{target}: no such directory {parent}", target)
    if real.exists():
        if real.is_dir() != directory:
            kind = "a directory" if real.is_dir() else "not a directory"
            raise OutputRefused(f"{target}: is {kind}", target)
        if not directory and not stat.S_ISREG(real.stat().st_mode):
            raise OutputRefused(f"{target}: not a regular file", target)
        if not force:
            raise OutputRefused(f"{target}: exists", target, exists=True)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputRefused(f"{target}: cannot write into {parent}", target)
    partial = partial_path(real)
    if partial.exists():
        with contextlib.suppress(FileNotFoundError):  # gone meanwhile: nothing in the way
            os.close(_busy_or_stale(target, partial, partial.is_dir(), force))
    return real


class Output:
    """One file (or, ``directory=True``, one directory) written under ``NAME.partial`` and
    put in place by :meth:`commit`. Write the file through :meth:`file`; a directory's
    content is made at :attr:`path` (inside ``NAME.partial``, under the target's own name,
    so what it names after itself — a bag's ``NAME.mcap`` — is right once in place)."""

    def __init__(self, target: Path, *, force: bool, directory: bool = False) -> None:
        self.target = target
        self.directory = directory
        self.force = force
        self._real = check_target(target, force=force, directory=directory)
        self.partial = partial_path(self._real)
        self._fd = self._take()
        #: where to write: the partial file, or the directory to make inside the partial one
        self.path = self.partial / self._real.name if directory else self.partial
        self._done = False

    def _take(self) -> int:
        try:
            try:
                if self.directory:
                    os.mkdir(self.partial, 0o755)
                    fd = _open_partial(self.partial, True)
                else:
                    fd = os.open(self.partial, os.O_RDWR | os.O_CREAT | os.O_EXCL |
                                 os.O_CLOEXEC, 0o644)
            except FileExistsError:
                fd = _busy_or_stale(self.target, self.partial, self.directory, self.force)
                self._empty(fd)
                return fd
            if not _flock(fd):  # another writer opened it between our making and locking
                os.close(fd)
                raise OutputBusy(f"{self.target}: another process is writing it now")
        except RecordingError:
            raise
        except OSError as exc:
            raise RecordingError(f"{self.target}: cannot write: {exc.strerror or exc}"
                                 ) from None
        return fd

    def _empty(self, fd: int) -> None:
        """Take over a partial left by a writer that died (``force``)."""
        if not self.directory:
            os.ftruncate(fd, 0)
            return
        for child in self.partial.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child)
            else:
                child.unlink()

    def file(self) -> IO[bytes]:
        """The partial file, opened for writing (it shares the lock; closing it does not
        end the lock, :meth:`commit` or :meth:`discard` does)."""
        assert not self.directory
        return os.fdopen(os.dup(self._fd), "r+b")

    def commit(self) -> None:
        """Sync what was written and rename it into place; :class:`RecordingError` when it
        cannot be (the message says where what was written is)."""
        if self._done:
            return
        self._done = True
        try:
            self._sync()
            self._place()
            with contextlib.suppress(OSError):
                _fsync_directory(self._real.parent)
        except RecordingError:
            raise
        except OSError as exc:
            where = (f"what was written is in {self.partial}" if self.partial.exists() else
                     f"its directory {self._real.parent} is gone, and the recording with it"
                     if not self._real.parent.is_dir() else "nothing was kept")
            raise RecordingError(f"{self.target}: cannot put it in place: "
                                 f"{exc.strerror or exc}; {where}") from None
        finally:
            os.close(self._fd)

    def _sync(self) -> None:
        if not self.directory:
            os.fsync(self._fd)
            return
        for root, _dirs, files in os.walk(self.path):
            for name in files:
                fd = os.open(os.path.join(root, name), os.O_RDONLY | os.O_CLOEXEC)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
            _fsync_directory(Path(root))

    def _place(self) -> None:
        if self.directory:
            if self.force and self._real.exists():
                aside = self.partial / f"{self._real.name}.replaced"
                os.rename(self._real, aside)
            try:
                os.rename(self.path, self._real)
            except OSError as exc:
                if exc.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR):
                    raise RecordingError(f"{self.target}: made by another process meanwhile; "
                                         f"the recording is in {self.path}") from None
                raise
            shutil.rmtree(self.partial, ignore_errors=True)
            return
        if self.force:
            os.replace(self.partial, self._real)
            return
        try:
            os.link(self.partial, self._real)  # never replaces: EEXIST if it is there now
        except FileExistsError:
            raise RecordingError(f"{self.target}: made by another process meanwhile; the "
                                 f"recording is in {self.partial}") from None
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EMLINK):
                raise
            if self._real.exists():  # a filesystem without hard links: check, then rename
                raise RecordingError(f"{self.target}: made by another process meanwhile; "
                                     f"the recording is in {self.partial}") from None
            os.rename(self.partial, self._real)
            return
        os.unlink(self.partial)

    def discard(self) -> None:
        """Remove what was written (nothing of it is kept)."""
        if self._done:
            return
        self._done = True
        try:
            if self.directory:
                shutil.rmtree(self.partial, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    self.partial.unlink()
        finally:
            os.close(self._fd)

    def keep_partial(self) -> None:
        """Leave what was written where it is, under ``NAME.partial`` (not complete)."""
        if self._done:
            return
        self._done = True
        os.close(self._fd)


def _fsync_directory(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class DirectoryLock:
    """One writer at a time of a directory of recordings: an ``flock`` on the directory
    itself (made if missing; nothing is left in it), held from ``__enter__`` to
    ``__exit__``. Another process that holds it: :class:`OutputBusy`. Re-entrant within
    one process (the CLI holds it across a campaign whose runner takes it again). A
    directory that cannot be made or opened is not locked: nothing can be written there,
    and each writer says so."""

    _held: ClassVar[dict[tuple[int, int], list[int]]] = {}  # (dev, ino) → [fd, depth]

    def __init__(self, directory: Path, what: str = "campaign") -> None:
        self.directory = directory
        self.what = what
        self._key: tuple[int, int] | None = None

    def __enter__(self) -> DirectoryLock:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError:
            return self
        info = os.fstat(fd)
        key = (info.st_dev, info.st_ino)
        held = self._held.get(key)
        if held is not None:
            os.close(fd)
            held[1] += 1
            self._key = key
            return self
        if not _flock(fd):
            os.close(fd)
            raise OutputBusy(f"{self.directory}: another {self.what} is writing there now")
        self._held[key] = [fd, 1]
        self._key = key
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        key, self._key = self._key, None
        if key is None:
            return
        held = self._held[key]
        held[1] -= 1
        if held[1] == 0:
            del self._held[key]
            os.close(held[0])


# --- room for the summary ---------------------------------------------------------------------

_FALLOC_FL_KEEP_SIZE = 1


def _fallocate() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        function = libc.fallocate
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    return function


class ReservedSpace:
    """Keeps disk space allocated past the end of a file (the file's size does not change),
    and knows where its content was last complete."""

    def __init__(self, file: IO[bytes], reserve: int = RESERVE_BYTES) -> None:
        self._file = file
        self._reserve = reserve
        self._fallocate = _fallocate()
        self.good = 0  #: the offset up to which the file is complete

    def mark_good(self) -> None:
        """The file is complete as it stands: remember where, and reserve room ahead
        (:class:`DiskFull` when there is none)."""
        self._file.flush()
        self.good = self._file.tell()
        if self._fallocate is None:
            return
        if self._fallocate(self._file.fileno(), _FALLOC_FL_KEEP_SIZE, self.good,
                           self._reserve) != 0:
            code = ctypes.get_errno()
            if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise DiskFull(code, os.strerror(code))
            self._fallocate = None  # not supported here: writes will tell

    def cut_back(self) -> None:
        """Drop whatever came after the last complete state (a torn chunk or row)."""
        with contextlib.suppress(OSError, ValueError):
            self._file.seek(self.good)
            self._file.truncate(self.good)

    def release(self) -> None:
        """Give the room kept past the end back (the file is finished): a file's size set
        to what it is frees nothing on every filesystem, so it is grown by a byte, with a
        hole, and cut back to its size, which frees everything allocated past it."""
        with contextlib.suppress(OSError, ValueError):
            self._file.flush()
            size = self._file.seek(0, os.SEEK_END)
            self._file.truncate(size + 1)
            self._file.truncate(size)
