"""The record of the files a tool wrote into an output folder.

Each output folder that a tool writes (a simulation, its renders, an evaluation, a model, a
generated dataset) holds ``.written.json``: the paths, relative to the folder, of the files the
tools wrote there. Replacing a run (``--force``, a fresh run over an old one, a clean-up) removes
exactly those files and the folders that became empty, so a file that a user put into the folder
is never deleted.
"""
from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from fracture_gs.io.atomic import write_text_atomic

MANIFEST_FILE = ".written.json"


class Manifest:
    """The files written into one folder (paths relative to it, ``/``-separated)."""

    def __init__(self, folder: str | os.PathLike, files: Iterable[str] = ()) -> None:
        self.folder = Path(folder)
        self.files: set[str] = set(files)

    @property
    def path(self) -> Path:
        return self.folder / MANIFEST_FILE

    @classmethod
    def load(cls, folder: str | os.PathLike) -> "Manifest":
        """The folder's manifest; an empty one when it has none (or it cannot be read: then
        nothing counts as written by the tools)."""
        manifest = cls(folder)
        try:
            content = json.loads(manifest.path.read_text(encoding="utf-8"))
            files = content["files"]
            if isinstance(files, list):
                manifest.files = {str(f) for f in files if isinstance(f, str)}
        except (OSError, ValueError, KeyError, TypeError):
            pass
        return manifest

    def exists(self) -> bool:
        """Whether the folder holds a manifest file."""
        return self.path.is_file()

    def relative(self, path: str | os.PathLike) -> str:
        """``path`` (inside the folder) relative to it, as recorded."""
        return Path(os.path.relpath(Path(path).absolute(), self.folder.absolute())).as_posix()

    def add(self, *paths: str | os.PathLike) -> None:
        """Record ``paths`` as written by the tools (call :meth:`save` to keep it)."""
        self.files.update(self.relative(p) for p in paths)

    def __contains__(self, path: str | os.PathLike) -> bool:
        return self.relative(path) in self.files

    def save(self) -> None:
        """Write the manifest (atomically)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps({"files": sorted(self.files)}, indent=1) + "\n")

    def remove_written(self) -> list[Path]:
        """Delete the recorded files, then the folders below this one that became empty, then
        the manifest itself; returns the files deleted. Unrecorded files stay."""
        removed = []
        folders = set()
        for name in sorted(self.files):
            path = self.folder / name
            if ".." in Path(name).parts or Path(name).is_absolute():
                continue   # never outside the folder
            if path.is_file() or path.is_symlink():
                path.unlink()
                removed.append(path)
            folders.update(p for p in path.parents if self.folder in p.parents)
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            try:
                folder.rmdir()
            except OSError:
                pass   # not empty (a user's file) or already gone
        self.files = set()
        self.path.unlink(missing_ok=True)
        return removed


def file_stamps(folder: str | os.PathLike) -> dict[str, tuple[int, int]]:
    """(inode, mtime) of each file directly in ``folder``: taken before a tool writes, it
    tells afterwards which files the tool wrote (an atomic write gives a file a new inode)."""
    root = Path(folder)
    if not root.is_dir():
        return {}
    return {path.name: (path.stat().st_ino, path.stat().st_mtime_ns)
            for path in root.iterdir() if path.is_file()}


def record_written_since(folder: str | os.PathLike, before: dict[str, tuple[int, int]]) -> None:
    """Record in ``folder``'s manifest the files directly in it that are new or rewritten
    since the :func:`file_stamps` ``before``."""
    now = file_stamps(folder)
    manifest = Manifest.load(folder)
    manifest.add(*(Path(folder) / name for name, stamp in now.items()
                   if name != MANIFEST_FILE and before.get(name) != stamp))
    manifest.save()


def remove_written_tree(folder: str | os.PathLike,
                        separate: Callable[[Path], bool] | None = None) -> list[Path]:
    """:meth:`Manifest.remove_written` for ``folder`` and every folder below it that holds a
    manifest (a simulation with its renders and evaluation); returns the files deleted. A folder
    below for which ``separate(path)`` is true (another run kept inside this one) is left alone,
    with everything below it."""
    root = Path(folder)
    if not root.is_dir():
        return []
    manifests = [path.parent for path in root.rglob(MANIFEST_FILE)]
    apart = [path for path in manifests if path != root and separate is not None and separate(path)]
    removed = []
    for path in sorted(manifests, key=lambda p: len(p.parts), reverse=True):
        if not any(path == other or other in path.parents for other in apart):
            removed += Manifest.load(path).remove_written()
    return removed
