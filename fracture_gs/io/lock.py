"""An exclusive lock on an output folder while one run writes it.

The lock is an advisory ``flock`` on a small file in the folder (``.simulate.lock``,
``.train.lock``, ``.render.lock``, ``.evaluate.lock``, ...); the system releases it when the run
ends or its process dies, so it never goes stale. The run removes the file when it ends (while
still holding it: a run that opened the old file finds it gone and takes a new one), and a run
that made the folder for itself and left nothing in it (it stopped on bad input) removes the
folder too. Where ``fcntl`` is missing (Windows) the lock does nothing.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import IO
from pathlib import Path


class FolderBusy(ValueError):
    """Another run holds the folder's lock; the message is one line naming the folder."""


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, lock_name: str, tool: str,
                what: str = "folder") -> Iterator[None]:
    """Hold the lock file ``lock_name`` in ``folder`` (made if missing) for the block;
    ``tool`` and ``what`` name the command and the folder in the message. The file is deleted
    when the block ends, while the lock is still held (a run that finds the file it locked deleted
    under it locks the new one instead), and the folders this run made are removed if empty.

    Raises:
        FolderBusy: another process holds it.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        yield
        return
    root = Path(folder)
    made = [p for p in (root, *root.absolute().parents) if not p.exists()]
    path = root / lock_name
    while True:
        root.mkdir(parents=True, exist_ok=True)
        try:
            handle = open(path, "a+", encoding="utf-8")
        except FileNotFoundError:   # the folder went in between (a run that removed its own)
            continue
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise FolderBusy(f"{root}: another {tool} run is writing this {what} (it holds "
                             f"{lock_name}); wait for it or choose another output folder") from None
        if _same_file(handle, path):   # the file locked must still be the one at the path
            break
        handle.close()  # the holder before us removed the file: lock the one there now
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield
    finally:
        path.unlink(missing_ok=True)   # still locked: a run waiting on it sees the path gone
        for folder_made in made:       # deepest first, only the empty ones this run made
            try:
                folder_made.rmdir()
            except OSError:
                break
        handle.close()


def _same_file(handle: IO[str], path: Path) -> bool:
    """Whether the open ``handle`` is still the file at ``path``."""
    try:
        return os.path.samestat(os.fstat(handle.fileno()), os.stat(path))
    except OSError:
        return False
