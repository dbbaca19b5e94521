"""An exclusive lock on an output folder while one run writes it.

The lock is an advisory ``flock`` on a small file in the folder; the system releases it when
the run ends or its process dies, so it never goes stale. Where ``fcntl`` is missing (Windows)
the lock does nothing.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path


class FolderBusy(ValueError):
    """Another run holds the folder's lock; the message is one line naming the folder."""


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, lock_name: str, tool: str,
                what: str = "folder") -> Iterator[None]:
    """Hold the lock file ``lock_name`` in ``folder`` (made if missing) for the block;
    ``tool`` and ``what`` name the command and the folder in the message.

    Raises:
        FolderBusy: another process holds it.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        yield
        return
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    with open(root / lock_name, "a+", encoding="utf-8") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderBusy(f"{root}: another {tool} run is writing this {what} (it holds "
                             f"{lock_name}); wait for it or choose another output folder") from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield
