"""The background a simulation is rendered on when ``--background`` is not given: the one its
trained objects were trained on, so that the edges of their Gaussians, fitted against that
colour, blend as they did in training."""
from __future__ import annotations

from fracture_gs.config.scene import SceneConfig
from fracture_gs.folders.model_folder import read_cfg_args
from fracture_gs.io.model_layout import CFG_ARGS_FILE

BACKGROUNDS = ("white", "black")
DEFAULT_BACKGROUND = "white"


def training_background(scene: SceneConfig) -> str:
    """``"white"`` or ``"black"``: the training background (``cfg_args``' ``white_background``)
    of the first object with a trained model folder; white for scenes of primitives and for
    models without a readable ``cfg_args``."""
    for obj in scene.objects:
        if obj.model is None or not obj.model.is_dir():
            continue
        cfg = obj.model / CFG_ARGS_FILE
        if not cfg.is_file():
            continue
        try:
            options = read_cfg_args(str(cfg))
        except (OSError, ValueError):
            continue
        return "white" if options.get("white_background", False) else "black"
    return DEFAULT_BACKGROUND
