"""One writer per dataset: an exclusive advisory lock held for the life of a run."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from babblegen.config import ConfigError

LOCK_NAME = "run.lock"


class DatasetLock:
    """``flock`` on ``DIR/babblegen/run.lock``. The kernel drops it when the process ends, however it ends, so
    a killed run never leaves a stale lock behind."""

    def __init__(self, sidecar: Path):
        self.path = Path(sidecar) / LOCK_NAME
        self._fd: int | None = None

    def acquire(self, dataset: Path) -> None:
        """Take the lock, or raise ConfigError naming the run that holds it."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise ConfigError(
                f"{dataset} is in use by another babblegen run (pid {holder}); wait for it to finish or stop it "
                "(Ctrl-C), then --resume"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
