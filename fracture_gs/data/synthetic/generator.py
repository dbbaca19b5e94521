"""Generate one synthetic multi-view dataset (Blender / NeRF-synthetic layout, SPEC §3).

Output folder::

    transforms_train.json  transforms_test.json   camera_angle_x + frames (OpenGL c2w)
    train/r_<i>.png  test/r_<i>.png                RGBA, straight alpha = object mask
    gt_mesh.ply                                    the rendered mesh, for evaluation only
    parts.json                                     part spec in object (= world) coordinates
    generator.json                                 settings and timings of the run

Everything is written to ``<out>.partial`` first and renamed at the end, so an interrupted run
leaves no half-written dataset behind.
"""
from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from fracture_gs.data.parts import save_part_spec
from fracture_gs.data.synthetic import writer
from fracture_gs.data.synthetic.cameras import NERF_CAMERA_ANGLE_X, sphere_poses
from fracture_gs.data.synthetic.objects import SyntheticObject, build_object
from fracture_gs.data.synthetic.render_mitsuba import build_scene, render_view, require_mitsuba
from fracture_gs.data.synthetic.textures import linear_to_srgb


@dataclass(frozen=True)
class GeneratorSettings:
    width: int = 400
    height: int = 400
    n_train: int = 100
    n_test: int = 20
    spp: int = 16
    seed: int = 0
    resolution: int = 256

    def validate(self) -> None:
        checks = {"--width": self.width >= 8, "--height": self.height >= 8,
                  "--n-train": self.n_train >= 1, "--n-test": self.n_test >= 0,
                  "--spp": self.spp >= 1, "--grid": self.resolution >= 16}
        for option, ok in checks.items():
            if not ok:
                raise ValueError(f"{option}: value out of range ({self})")


def vertex_colors_srgb8(obj: SyntheticObject) -> np.ndarray:
    """Per-vertex RGBA uint8 colours of the whole mesh (a vertex on a part border takes the
    colour of the last part that uses it)."""
    colors = np.full((len(obj.mesh.vertices), 4), 255, dtype=np.uint8)
    for piece in obj.pieces():
        used = np.unique(obj.mesh.faces[obj.face_parts == piece.part])
        colors[used, :3] = np.round(linear_to_srgb(piece.colors) * 255).astype(np.uint8)
    return colors


def generate_dataset(name: str, out: str, settings: GeneratorSettings = GeneratorSettings(),
                     overwrite: bool = False, progress: bool = True) -> dict:
    """Build, render and write one object's dataset into ``out``; returns the run summary."""
    settings.validate()
    if os.path.exists(out) and not overwrite:
        raise FileExistsError(f"{out}: already exists (use --force to replace it)")
    require_mitsuba()
    started = time.perf_counter()
    obj = build_object(name, settings.resolution, settings.seed)
    mesh_seconds = time.perf_counter() - started
    scene = build_scene(obj)
    partial = out.rstrip("/") + ".partial"
    shutil.rmtree(partial, ignore_errors=True)
    try:
        writer.ensure_dir(partial)
        train_poses, test_poses = sphere_poses(settings.n_train, settings.n_test, settings.seed)
        render_started = time.perf_counter()
        views = [("train", i, pose) for i, pose in enumerate(train_poses)]
        views += [("test", i, pose) for i, pose in enumerate(test_poses)]
        for number, (split, index, pose) in enumerate(
                tqdm(views, desc=f"render {name}", unit="view", disable=not progress)):
            image = render_view(scene, pose, NERF_CAMERA_ANGLE_X, settings.width,
                                settings.height, settings.spp,
                                seed=settings.seed * 100003 + number)
            writer.write_png(os.path.join(writer.ensure_dir(os.path.join(partial, split)),
                                          f"r_{index}.png"),
                             writer.rgba8_from_premultiplied(image))
        render_seconds = time.perf_counter() - render_started
        for split, poses in (("train", train_poses), ("test", test_poses)):
            writer.write_transforms(os.path.join(partial, f"transforms_{split}.json"),
                                    NERF_CAMERA_ANGLE_X,
                                    [f"./{split}/r_{i}" for i in range(len(poses))], poses)
        writer.write_mesh(os.path.join(partial, "gt_mesh.ply"), obj.mesh, vertex_colors_srgb8(obj))
        save_part_spec(obj.part_spec, os.path.join(partial, "parts.json"), extra={
            "object": name,
            "frame": "object coordinates = dataset world coordinates (z up)",
            "normalization": {"center": obj.center.tolist(), "scale": obj.scale,
                              "note": "p = (p_natural - center) * scale; the object fits in "
                                      "the unit sphere"}})
        summary = {"object": name, "description": obj.description,
                   "settings": settings.__dict__, "faces": int(len(obj.mesh.faces)),
                   "watertight": bool(obj.mesh.is_watertight),
                   "mesh_seconds": round(mesh_seconds, 2),
                   "render_seconds": round(render_seconds, 2),
                   "seconds_per_view": round(render_seconds / len(views), 3),
                   "total_seconds": round(time.perf_counter() - started, 2)}
        writer.write_json(os.path.join(partial, "generator.json"), summary)
        if os.path.exists(out):
            shutil.rmtree(out)
        os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return summary
