"""The record of the files a tool wrote into an output folder.

Each output folder that a tool writes (a simulation, its renders, an evaluation, a model's
renders, a generated dataset, the demo) holds ``.written.json``: what kind of output the folder
holds, the paths (relative to the folder) of the files the tools wrote there, and the identity of
the folder it was written in (its real absolute path, device and inode number). Replacing a run
(``--force``, a fresh run over an old one, a clean-up) removes exactly those files and the folders
that became empty, so a file that a user put into the folder is never deleted.

A manifest vouches only for the folder it was written in: a copy of the folder (``cp -a``, a
backup, a restored archive) or a folder moved elsewhere gets a new path or inode, and its copied
manifest then vouches for nothing, so no tool deletes or overwrites the copy's files. A manifest of
an older version (without the identity) vouches for nothing either. :func:`claim_folder` is the
check every writing command makes before it writes: each file it will write must be absent or
recorded in the folder's manifest, and the folder must not hold another kind of output.
"""
from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from fracture_gs.io.atomic import write_text_atomic

MANIFEST_FILE = ".written.json"

# the kinds of output folder, and the command that writes each (for messages)
KIND_TOOLS = {"simulation": "simulate.py", "render": "render.py --sim",
              "evaluation": "evaluate.py", "model-render": "render.py -m",
              "dataset": "the dataset generator", "demo": "demo.py", "model": "train.py"}
# kinds whose folders are outputs of their own, never part of a folder around them
STANDALONE_KINDS = ("simulation", "dataset", "demo", "model")


class FolderTaken(ValueError):
    """An output folder that a command may not write: a file in the way that the tools did not
    write there, or another kind of output. The message is one line naming the folder or file."""


def folder_identity(folder: str | os.PathLike) -> dict[str, Any] | None:
    """The identity a manifest records: real absolute path, device and inode of the folder
    (None when it does not exist)."""
    try:
        stat = os.stat(folder)
    except OSError:
        return None
    return {"folder": os.path.realpath(folder), "device": stat.st_dev, "inode": stat.st_ino}


class Manifest:
    """The files written into one folder (paths relative to it, ``/``-separated).

    ``kind`` names what the folder holds (a key of :data:`KIND_TOOLS`, '' when unknown);
    ``foreign`` is true when the folder holds a manifest that vouches for nothing here (copied
    from or left by another folder, or written by an older version)."""

    def __init__(self, folder: str | os.PathLike, files: Iterable[str] = (),
                 kind: str = "") -> None:
        self.folder = Path(folder)
        self.files: set[str] = set(files)
        self.kind = kind
        self.foreign = False

    @property
    def path(self) -> Path:
        return self.folder / MANIFEST_FILE

    @classmethod
    def load(cls, folder: str | os.PathLike) -> "Manifest":
        """The folder's manifest; an empty one when it has none, cannot be read, or was
        written for another folder (then nothing counts as written by the tools, and
        ``foreign`` says why)."""
        manifest = cls(folder)
        try:
            content = json.loads(manifest.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            manifest.foreign = manifest.path.exists()
            return manifest
        if not isinstance(content, dict):
            manifest.foreign = True
            return manifest
        identity = folder_identity(folder)
        recorded = {key: content.get(key) for key in ("folder", "device", "inode")}
        files = content.get("files")
        if identity is None or recorded != identity or not isinstance(files, list):
            manifest.foreign = True
            return manifest
        manifest.files = {str(f) for f in files if isinstance(f, str)}
        manifest.kind = str(content.get("kind", ""))
        return manifest

    def exists(self) -> bool:
        """Whether the folder holds a manifest that vouches for it."""
        return self.path.is_file() and not self.foreign

    def relative(self, path: str | os.PathLike) -> str:
        """``path`` (inside the folder) relative to it, as recorded."""
        return Path(os.path.relpath(Path(path).absolute(), self.folder.absolute())).as_posix()

    def add(self, *paths: str | os.PathLike) -> None:
        """Record ``paths`` as written by the tools (call :meth:`save` to keep it)."""
        self.files.update(self.relative(p) for p in paths)

    def __contains__(self, path: str | os.PathLike) -> bool:
        return self.relative(path) in self.files

    def save(self) -> None:
        """Write the manifest (atomically), bound to the folder it is in."""
        self.folder.mkdir(parents=True, exist_ok=True)
        content = {**(folder_identity(self.folder) or {}), "kind": self.kind,
                   "files": sorted(self.files)}
        write_text_atomic(self.path, json.dumps(content, indent=1) + "\n")
        self.foreign = False

    def remove_written(self) -> list[Path]:
        """Delete the recorded files, then the folders below this one that became empty, then
        the manifest itself; returns the files deleted. Unrecorded files stay (and a manifest
        that vouches for nothing here is left as it is)."""
        if self.foreign:
            return []
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


def claim_folder(folder: str | os.PathLike, kind: str, paths: Iterable[str | os.PathLike],
                 option: str = "--out") -> Manifest:
    """The manifest of ``folder`` once it is clear that a command writing output of ``kind``
    may write ``paths`` there: each is absent or recorded in the folder's manifest, and the
    folder holds no other kind of output. Nothing is written.

    Raises:
        FolderTaken: one line naming the folder or the first file in the way.
    """
    root = Path(folder)
    manifest = Manifest.load(root)
    if manifest.files and manifest.kind != kind:
        holder = KIND_TOOLS.get(manifest.kind, "another command")
        raise FolderTaken(f"{option}: {root} holds the output of {holder} ({MANIFEST_FILE}); "
                          f"choose another folder for {KIND_TOOLS[kind]}")
    for path in paths:
        path = Path(path)
        if os.path.lexists(path) and (path.is_dir() or path not in manifest):
            why = (f" (its {MANIFEST_FILE} was not written for this folder: that of a copied "
                   "or moved folder, or of an older version, vouches for nothing)"
                   if manifest.foreign else "")
            raise FolderTaken(f"{option}: {path} is in the way: the tools did not write it in "
                              f"{root}{why}; move it away or choose another folder")
    manifest.kind = kind
    return manifest


def replace_written(manifest: Manifest, files: Iterable[str | os.PathLike]) -> Manifest:
    """Remove the files ``manifest`` (from :func:`claim_folder`) records, then record ``files``
    in a new manifest of the same folder and kind (saved before they are written, so an
    interrupted command's files are known too); returns it."""
    manifest.remove_written()
    fresh = Manifest(manifest.folder, kind=manifest.kind)
    fresh.add(*files)
    fresh.save()
    return fresh


def remove_written_tree(folder: str | os.PathLike,
                        separate: Callable[[Path], bool] | None = None) -> list[Path]:
    """:meth:`Manifest.remove_written` for ``folder`` and every folder below it whose manifest
    vouches for it (a simulation with its renders and evaluation); returns the files deleted. A
    folder below that holds output of its own (:data:`STANDALONE_KINDS`), for which
    ``separate(path)`` is true (another run kept inside this one), or whose manifest vouches for
    nothing (a copy) is left alone, with everything below it."""
    root = Path(folder)
    if not root.is_dir():
        return []
    manifests = {path.parent: Manifest.load(path.parent) for path in root.rglob(MANIFEST_FILE)}
    apart = [path for path, manifest in manifests.items() if path != root and (
        manifest.foreign or manifest.kind in STANDALONE_KINDS or
        (separate is not None and separate(path)))]
    removed = []
    for path in sorted(manifests, key=lambda p: len(p.parts), reverse=True):
        if not any(path == other or other in path.parents for other in apart):
            removed += manifests[path].remove_written()
    return removed
