"""Reading dataset files so that every failure is one line naming the file.

The loaders read through these helpers instead of ``open`` / ``cv2.imread`` / ``np.load``
directly: a missing file, a folder where a file belongs, a file without read permission or
any other ``OSError`` becomes a :class:`DatasetError` ``"<path>: cannot read (<reason>)"``,
never a traceback (``cv2.imread`` would even return ``None`` for an unreadable file, which
reads as "not an image").
"""
from __future__ import annotations

import io
import json
import os
import zipfile
from collections.abc import Callable

import numpy as np

from fracture_gs.data.dataset import DatasetError


def os_reason(error: OSError) -> str:
    """The short reason of an ``OSError`` ("Permission denied"), without the file name."""
    return error.strerror or type(error).__name__


def read_bytes(path: str, error: Callable[[str], Exception] = DatasetError) -> bytes:
    """The content of ``path``; ``error("<path>: ...")`` (a DatasetError by default) if it is
    missing, a folder, or cannot be read."""
    if os.path.isdir(path):
        raise error(f"{path}: is a folder, expected a file")
    try:
        with open(path, "rb") as handle:
            return handle.read()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({os_reason(exc)})") from None


def read_text(path: str, error: Callable[[str], Exception] = DatasetError,
              errors: str = "strict") -> str:
    """``path`` decoded as UTF-8 (``errors`` as for ``bytes.decode``)."""
    data = read_bytes(path, error)
    try:
        return data.decode("utf-8", errors=errors)
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file (byte {exc.start})") from None


def read_json(path: str, error: Callable[[str], Exception] = DatasetError) -> object:
    """Parsed JSON content of ``path``."""
    text = read_text(path, error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: invalid JSON: {exc}") from None
    except RecursionError:
        raise error(f"{path}: invalid JSON: lists or objects nested too deeply") from None


def read_npz(path: str) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive (no pickled objects)."""
    data = read_bytes(path)
    if not data.startswith(b"PK"):
        raise DatasetError(f"{path}: cannot be read as an .npz archive (not a zip file)")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DatasetError(f"{path}: cannot be read as an .npz archive ({exc})") from None
