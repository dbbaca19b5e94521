"""The cameras a ``--views`` spec names for a simulation or a model: orbits around the run, a
``cameras.json``, or the ``train`` / ``test`` cameras of the dataset a model was trained on, moved
into the scene (render.py, evaluate.py, the figure scripts and the benchmarks frame a run the same
way)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fracture_gs.data import load_dataset
from fracture_gs.data.dataset import DatasetError
from fracture_gs.folders.model_folder import read_cfg_args
from fracture_gs.folders.sim_reader import Simulation
from fracture_gs.io.model_layout import CFG_ARGS_FILE
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.mpm.scene import rotation_matrix_xyz
from fracture_gs.render.views import (View, ViewSpecError, bounds_sphere, cameras_from_json,
                                      check_image_size, orbit_views, resize_camera, safe_view_name,
                                      transform_camera, unique_view_names)

DEFAULT_ORBIT_SIZE = (800, 800)


def resolve_views(spec: str, sim: Simulation, frames: Sequence[int],
                  size: tuple[int, int] | None) -> list[View]:
    """The cameras named by ``--views`` for this simulation (ViewSpecError naming the spec)."""
    if spec.startswith("orbit:"):
        count_text = spec[len("orbit:"):]
        if not count_text.isdigit() or int(count_text) < 1:
            raise ViewSpecError(f"--views {spec}: orbit:N needs a whole number N >= 1")
        points = [sim.particles.rest_x, sim.load_frame(frames[-1]).x.numpy()]
        centre, radius = bounds_sphere(np.concatenate(points))
        gravity = np.asarray(sim.scene.gravity, dtype=np.float64)
        up = -gravity / np.linalg.norm(gravity) if np.linalg.norm(gravity) > 0 else (0, 0, 1)
        width, height = size if size is not None else DEFAULT_ORBIT_SIZE
        return orbit_views(int(count_text), centre, radius, width, height, up=up)
    if spec in ("train", "test"):
        trained = [obj for obj in sim.scene.objects if obj.model is not None and obj.model.is_dir()]
        if not trained:
            raise ViewSpecError(f"--views {spec}: no object of {SimLayout(sim.root).scene_path} "
                                "has a trained model folder")
        obj = trained[0]
        return dataset_views(obj.model, spec, rotation_matrix_xyz(obj.transform.rotate_deg),
                             obj.transform.scale, obj.transform.translate, size)
    path = Path(spec)
    if path.suffix.lower() == ".json" or path.exists():
        return cameras_from_json(path, size)
    raise ViewSpecError(f"--views {spec}: unknown view spec (orbit:N, train, test or a "
                        "cameras.json)")


def dataset_source(model_dir: Path) -> tuple[Path, int]:
    """The dataset folder a model was trained on (``source_path`` in its ``cfg_args``) and the
    ``--holdout-every`` it was trained with (0 when not recorded)."""
    cfg = model_dir / CFG_ARGS_FILE
    if not cfg.is_file():
        raise ViewSpecError(f"{cfg}: file not found (train/test views need the model's "
                            "cfg_args with source_path)")
    try:
        options = read_cfg_args(str(cfg))
    except (OSError, ValueError) as exc:
        raise ViewSpecError(str(exc)) from None
    if not options.get("source_path"):
        raise ViewSpecError(f"{cfg}: no source_path in it")
    source = Path(options["source_path"])
    if not source.is_absolute():
        source = (model_dir / source) if (model_dir / source).exists() else Path.cwd() / source
    if not source.exists():
        raise ViewSpecError(f"{cfg}: the dataset {source} does not exist")
    return source, int(options.get("holdout_every", 0) or 0)


def dataset_views(model_dir: Path, split: str, rotation: np.ndarray, scale: float,
                  translate: Sequence[float], size: tuple[int, int] | None) -> list[View]:
    """The ``split`` cameras of a model's dataset, moved into the scene by the object transform."""
    if size is not None:
        check_image_size(*size, f"--views {split}")
    source, holdout_every = dataset_source(model_dir)
    try:
        data = load_dataset(str(source), split=split, holdout_every=holdout_every)
    except DatasetError as exc:
        raise ViewSpecError(f"--views {split}: {exc}") from None
    views = []
    for name, camera in zip(data.image_paths, data.cameras):
        camera = transform_camera(camera, rotation, scale, translate)
        if size is not None:
            camera = resize_camera(camera, *size)
        views.append(View(safe_view_name(f"{split}_{Path(name).stem}"), camera))
    if not views:
        raise ViewSpecError(f"--views {split}: {source} has no {split} views")
    return unique_view_names(views)
