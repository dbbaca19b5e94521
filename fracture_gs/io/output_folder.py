"""Output folders of the command-line tools, made before any work starts.

A folder that cannot be made or written (a parent that is a file, a read-only or missing mount,
``/proc``) is bad input: every tool reports it as one ``error: ...`` line with exit status 2
before it loads data or simulates, instead of a traceback minutes later. Errors while writing
later on (a full disk) are ordinary ``OSError``s that name their file (:func:`naming_file`),
reported by :func:`os_error_line`.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


class OutputFolderError(ValueError):
    """An output folder that cannot be made or written: ``"<option>: <problem>"``."""

    def __init__(self, option: str, problem: str) -> None:
        self.option = option
        self.problem = problem
        super().__init__(f"{option}: {problem}")


def prepare_output_folder(path: str | os.PathLike, option: str, keep: bool = True) -> Path:
    """Make ``path`` (and its parents) and check that a file can be created in it.

    Args:
        path: the folder the tool will write into.
        option: the command-line option that chose it (for the message), e.g. ``"--out"``.
        keep: False only checks: the folders this call made are removed again, so that a run
            that stops on later bad input leaves nothing behind.

    Raises:
        OutputFolderError: the folder cannot be made, is not a folder, or is not writable.
    """
    folder = Path(path)
    missing = [p for p in (folder, *folder.absolute().parents) if not p.exists()]
    try:
        _make_writable_folder(folder, option)
    finally:
        if not keep:
            for made in missing:  # deepest first; only folders this call made, left empty
                if not made.is_dir():
                    continue  # never made (the mkdir failed below it)
                try:
                    made.rmdir()
                except OSError:
                    break
    return folder


def _make_writable_folder(folder: Path, option: str) -> None:
    existing = folder
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        problem = (f"'{folder}' is a file, not a folder" if existing == folder else
                   f"'{folder}' cannot be created: '{existing}' is a file")
        raise OutputFolderError(option, problem)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(option, f"'{folder}' cannot be created "
                                         f"({exc.strerror or exc})") from None
    try:  # os.access says yes to root everywhere; creating a file is the real test
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OutputFolderError(option, f"'{folder}' cannot be written "
                                         f"({exc.strerror or exc})") from None


@contextlib.contextmanager
def naming_file(path: str | os.PathLike, *aliases: str | os.PathLike) -> Iterator[None]:
    """Re-raise an ``OSError`` of the block that names no file, or names one of ``aliases`` (a
    temporary file written for ``path``), as one that names ``path``. A write that fails on a
    full disk says only "No space left on device"; the message then says which file it was."""
    try:
        yield
    except OSError as exc:
        if exc.errno is None or (exc.filename is not None and
                                 os.fspath(exc.filename) not in map(os.fspath, aliases)):
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), os.fspath(path)) from exc


def os_error_line(exc: OSError) -> str:
    """One line for an OSError: the file it concerns and the reason."""
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"
