"""Shared ways of filling the disk on real paths: a file-size limit
(``RLIMIT_FSIZE``: the kernel refuses writes past N bytes of any file with EFBIG) and a file object
that raises ``OSError(ENOSPC)`` once full, for a writer module's ``open``."""

from __future__ import annotations

import errno
import resource
import signal
from contextlib import contextmanager


@contextmanager
def file_size_limit(nbytes: int):
    """Writes past ``nbytes`` of any file fail (EFBIG) while the block runs."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)


class FullFile:
    """A file object that takes ``room`` bytes, then raises ENOSPC like a full disk."""

    def __init__(self, fh, room: int):
        self.fh, self.room = fh, room

    def write(self, data) -> int:
        if len(data) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= len(data)
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)


def full_disk_open(room: int):
    """``open`` for a writer module: files opened for writing fill up after ``room`` bytes."""
    def fake(path, mode="r", *a, **k):
        fh = open(path, mode, *a, **k)
        return FullFile(fh, room) if "w" in mode else fh
    return fake
