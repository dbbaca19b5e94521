"""The one atomic file write of the project.

A file is written under a temporary name in its own folder (``.<name>.<random>.tmp<suffix>``:
hidden, unique per writer, with the target's suffix so that encoders that go by the extension
work), flushed to the disk, given the permissions an ordinary new file gets, and renamed over
the target. Readers therefore see the old file or the complete new one, never a part; when the
write fails (or is interrupted) the temporary file is removed and the target is left as it was.
"""
from __future__ import annotations

import contextlib
import io
import os
import tempfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import numpy as np

from fracture_gs.io.output_folder import naming_file

TEMPORARY_GLOB = ".*.tmp*"   # the names temporary_beside makes


def temporary_beside(path: str | os.PathLike) -> Path:
    """A new, empty temporary file in the folder of ``path`` (the folder is made if missing)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{target.suffix}",
                                    dir=target.parent)
    os.close(handle)
    return Path(name)


def commit(temporary: Path, path: str | os.PathLike) -> None:
    """Flush ``temporary`` to the disk, give it ordinary file permissions and rename it to
    ``path``."""
    with open(temporary, "rb+") as handle:
        os.fsync(handle.fileno())
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(temporary, 0o666 & ~umask)   # mkstemp makes 0600 files
    os.replace(temporary, path)


def discard(temporary: Path) -> None:
    """Remove a temporary file that will not be committed (missing is fine)."""
    temporary.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; it replaces ``path`` when the
    block ends without an exception and is removed otherwise. An ``OSError`` that names no file
    (a full disk) or the temporary one is raised naming ``path``."""
    with naming_file(path):
        temporary = temporary_beside(path)
    with naming_file(path, temporary):
        try:
            yield temporary
            commit(temporary, path)
        finally:
            discard(temporary)


def atomic_write(path: str | os.PathLike, write: Callable[[io.BufferedWriter], None]) -> None:
    """Write ``path`` through ``write(handle)`` (a binary file handle), atomically."""
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        write(handle)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    atomic_write(path, lambda handle: handle.write(data))


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def save_npz_atomic(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` as an uncompressed ``.npz`` archive atomically."""
    atomic_write(path, lambda handle: np.savez(handle, **arrays))


def remove_temporaries(folder: Path) -> None:
    """Delete the temporary files that killed writers left in ``folder`` (never a complete
    file)."""
    if folder.is_dir():
        for temporary in folder.glob(TEMPORARY_GLOB):
            if temporary.is_file():
                temporary.unlink(missing_ok=True)
