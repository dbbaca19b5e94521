"""The train stage: a model folder from a dataset (the reconstruction itself is
:func:`fracture_gs.recon.pipeline.train`)."""
from __future__ import annotations

from typing import Any, TextIO

from fracture_gs.data import DatasetError
from fracture_gs.data.loading import detect_format
from fracture_gs.data.parts import PartSpecError
from fracture_gs.gaussians import PlyFormatError
from fracture_gs.io.lock import FolderBusy
from fracture_gs.io.output_folder import OutputFolderError, prepare_output_folder
from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.pipeline import TrainConfig, train

# what train_model raises for bad input (one line each; nothing half-written is left)
TRAIN_INPUT_ERRORS = (ReconstructionError, DatasetError, PartSpecError, PlyFormatError,
                      OutputFolderError, FolderBusy)


def train_model(config: TrainConfig, out: TextIO | None = None) -> dict[str, Any]:
    """Check the dataset and the model folder, then train; returns the run's summary (also in
    ``timings.json``). Raises one of :data:`TRAIN_INPUT_ERRORS` for bad input."""
    detect_format(config.source_path)  # a dataset before an output folder is made for it
    prepare_output_folder(config.model_path, "-m/--model_path", keep=False)
    return train(config, out)
