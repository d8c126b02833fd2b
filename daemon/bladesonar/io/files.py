"""File edges shared by the loaders and writers: bounded reads, atomic writes and stale
temp files.

Every loader decides its limit before it reads: a file (or /dev/zero, a FIFO) is read at
most ``limit + 1`` bytes, so a hostile size never reaches memory.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

from ..text import human_bytes


class TooLarge(Exception):
    """The file holds more than the caller's limit (``size`` is a lower bound if not a
    regular file)."""

    def __init__(self, size: int, limit: int) -> None:
        super().__init__(f"larger than {human_bytes(limit)}")
        self.size, self.limit = size, limit


class NotAFile(Exception):
    """The path is a directory or another kind of file a loader cannot read."""


def read_capped(path: str | Path, limit: int) -> bytes:
    """The bytes of ``path``, refusing before reading if its size is over ``limit``.

    Regular files are checked by size first; character devices and FIFOs (/dev/stdin,
    a shell's <(...)) are read at most ``limit + 1`` bytes, so /dev/zero is refused as
    too large rather than filling memory. Raises OSError, TooLarge or NotAFile.
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise NotAFile("is a directory")
        if not (stat.S_ISREG(st.st_mode) or stat.S_ISCHR(st.st_mode)
                or stat.S_ISFIFO(st.st_mode)):
            raise NotAFile("is not a regular file")
        if stat.S_ISREG(st.st_mode) and st.st_size > limit:
            raise TooLarge(st.st_size, limit)
        chunks: list[bytes] = []
        got = 0
        while got <= limit:
            b = os.read(fd, min(1 << 20, limit + 1 - got))
            if not b:
                break
            chunks.append(b)
            got += len(b)
        if got > limit:
            raise TooLarge(got, limit)
        return b"".join(chunks)
    finally:
        os.close(fd)


#: Hidden temporary files of an interrupted write older than this are removed by the next
#: command that writes the same path (``run`` for its reference, ``reference``,
#: ``simulate``); younger ones may belong to a write in progress (a write refreshes its
#: file's mtime; a reference is written in well under a second).
STALE_TEMP_S = 60.0


def temp_prefix(path: Path) -> str:
    """Prefix of the hidden temporary files an atomic write of ``path`` uses."""
    return f".{path.name}."


@contextlib.contextmanager
def atomic_writer(path: str | Path) -> Iterator[IO[bytes]]:
    """A binary file that appears at ``path`` only when the block ends without error
    (:class:`AtomicFile` in one block): on any error (a full disk, a signal) the
    temporary file is removed and ``path`` is left as it was."""
    out = AtomicFile(path)
    try:
        yield out.file
    except BaseException:
        out.abort()
        raise
    out.commit()


class AtomicFile:
    """A file written piece by piece that appears at ``path`` only on :meth:`commit`:
    it is written to ``.NAME.XXXX.tmp`` in the same folder, then flushed, fsynced,
    renamed over ``path`` and the folder fsynced; :meth:`abort` (or a failed commit)
    removes the temporary file and leaves ``path`` as it was. For writers that stream
    (WAV, truth sidecar); :func:`atomic_writer` is the one-block form."""

    def __init__(self, path: str | Path, mode: str = "wb") -> None:
        self.path = Path(path)
        self.folder = self.path.parent if str(self.path.parent) else Path(".")
        fd, self._tmp = tempfile.mkstemp(prefix=temp_prefix(self.path), suffix=".tmp",
                                         dir=self.folder)
        self.file: IO[Any] = os.fdopen(fd, mode, encoding=None if "b" in mode else "utf-8")
        self.done = False

    def commit(self, last: Callable[[], object] | None = None) -> None:
        """Write ``last()`` (a trailer, a header's final sizes), then put the file in
        place; on any error remove it instead."""
        if self.done:
            return
        try:
            if last is not None:
                last()
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            os.replace(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self.done = True
        with contextlib.suppress(OSError):
            dfd = os.open(self.folder, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)

    def abort(self) -> None:
        self.done = True
        with contextlib.suppress(OSError):
            self.file.close()
        with contextlib.suppress(OSError):
            os.unlink(self._tmp)


def remove_stale_temps(path: str | Path, older_than_s: float = 0.0) -> list[Path]:
    """Delete hidden ``.NAME.*.tmp`` files an atomic write of ``path`` left behind (a
    kill -9 or power loss mid-write); returns what was removed. Only files matching that
    exact pattern, owned by nobody else's write (older than ``older_than_s``), go."""
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    removed: list[Path] = []
    now = time.time()
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    prefix = temp_prefix(p)
    for name in names:
        if not (name.startswith(prefix) and name.endswith(".tmp")):
            continue
        q = folder / name
        try:
            st = q.lstat()
            if stat.S_ISREG(st.st_mode) and now - st.st_mtime >= older_than_s:
                q.unlink()
                removed.append(q)
        except OSError:
            continue
    return removed
