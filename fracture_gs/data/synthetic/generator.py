"""Generate one synthetic multi-view dataset (Blender / NeRF-synthetic layout, docs/file_formats.md §1).

Output folder::

    transforms_train.json  transforms_test.json   camera_angle_x + frames (OpenGL c2w)
    train/r_<i>.png  test/r_<i>.png                RGBA, straight alpha = object mask
    gt_mesh.ply                                    the rendered mesh, for evaluation only
    parts.json                                     part spec in object (= world) coordinates
    generator.json                                 settings and timings of the run

Everything is written to ``<out>.partial`` first and renamed at the end, so an interrupted run
leaves no half-written dataset behind. An existing ``out`` is only ever replaced (``--force``)
when it is a dataset this generator wrote, i.e. a folder with its ``generator.json``; a folder
holding anything else is refused before any work starts, so ``--out data/ --force`` cannot
delete ``data/``; a copy of a dataset (whose copied manifest vouches for nothing,
:mod:`fracture_gs.io.manifest`) is refused too. One run at a time writes a dataset folder: the
lock ``<parent>/.<name>.generate.lock`` (:mod:`fracture_gs.io.lock`) is held while a run writes
``<out>.partial`` and ``<out>``, and removed when it ends.
"""
from __future__ import annotations

import os
import re
import shutil
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from fracture_gs.bounds import SEED_MAX
from fracture_gs.data.parts import save_part_spec
from fracture_gs.data.synthetic import writer
from fracture_gs.data.synthetic.cameras import NERF_CAMERA_ANGLE_X, sphere_poses
from fracture_gs.data.synthetic.objects import SyntheticObject, build_object
from fracture_gs.data.synthetic.render_mitsuba import build_scene, render_view, require_mitsuba
from fracture_gs.data.synthetic.textures import linear_to_srgb
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import MANIFEST_FILE, Manifest
from fracture_gs.io.output_folder import OutputFolderError


GENERATOR_FILE = "generator.json"            # marks a folder as a generated dataset
GENERATED_NAMES = ("transforms_train.json", "transforms_test.json", "gt_mesh.ply", "parts.json",
                   GENERATOR_FILE)
PARTIAL_MARKER = ".generator_partial.json"   # marks a staging folder of an unfinished run
KIND = "dataset"                             # the manifest kind of a generated dataset


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
        if not 0 <= self.seed <= SEED_MAX:
            raise ValueError(f"--seed: {self.seed} is not within [0, {SEED_MAX}]")

    def view_seed(self, number: int) -> int:
        """Mitsuba's sampler seed of the ``number``-th view (Mitsuba takes 32-bit seeds)."""
        return (self.seed * 100003 + number) % 2 ** 32


def vertex_colors_srgb8(obj: SyntheticObject) -> np.ndarray:
    """Per-vertex RGBA uint8 colours of the whole mesh (a vertex on a part border takes the
    colour of the last part that uses it)."""
    colors = np.full((len(obj.mesh.vertices), 4), 255, dtype=np.uint8)
    for piece in obj.pieces():
        used = np.unique(obj.mesh.faces[obj.face_parts == piece.part])
        colors[used, :3] = np.round(linear_to_srgb(piece.colors) * 255).astype(np.uint8)
    return colors


def _is_empty_folder(path: str) -> bool:
    return os.path.isdir(path) and not os.path.islink(path) and not os.listdir(path)


def check_output_folder(out: str, overwrite: bool) -> None:
    """FileExistsError unless ``out`` may receive a new dataset.

    It may when it does not exist; with ``overwrite`` (``--force``) also when it is an empty
    folder or a folder this generator wrote (it holds ``generator.json``). Anything else (a
    file, a link, a folder with other content) is never replaced. The staging folder
    ``<out>.partial`` may only hold an earlier run's leftovers (its marker file).
    """
    partial = partial_folder(out)
    if os.path.lexists(partial) and not _is_empty_folder(partial) and \
            not os.path.isfile(os.path.join(partial, PARTIAL_MARKER)):
        raise FileExistsError(f"{partial}: exists and is not a staging folder of this generator; "
                              "move it away or choose another --out")
    _check_target(out, overwrite)


def _check_target(out: str, overwrite: bool) -> None:
    """The ``out`` half of :func:`check_output_folder`."""
    if not os.path.lexists(out):
        return
    if os.path.islink(out) or not os.path.isdir(out):
        raise FileExistsError(f"{out}: exists and is not a folder; choose another --out")
    if not _is_empty_folder(out) and not os.path.isfile(os.path.join(out, GENERATOR_FILE)):
        raise FileExistsError(f"{out}: exists and was not written by this generator (no "
                              f"{GENERATOR_FILE}); --force only replaces generated datasets, so "
                              "choose another --out (e.g. a sub-folder) or remove it yourself")
    manifest = Manifest.load(out)
    if manifest.foreign or (manifest.exists() and manifest.kind != KIND):
        raise FileExistsError(f"{out}: its {MANIFEST_FILE} was not written for this folder by "
                              "the generator (a copied or moved dataset, or one of an older "
                              "version); --force replaces only a dataset generated here, so "
                              "choose another --out or remove it yourself")
    if not overwrite:
        raise FileExistsError(f"{out}: already exists (use --force to replace it)")


def partial_folder(out: str) -> str:
    """The staging folder a run writes before renaming it to ``out``."""
    return os.path.normpath(out) + ".partial"


def _generated_files(folder: str) -> list[str]:
    """The files of ``folder`` (relative paths) that the generator wrote: its manifest, or in a
    dataset made before it kept one, the names the generator writes."""
    manifest = Manifest.load(folder)
    if manifest.exists():
        return sorted(manifest.files)
    found = [name for name in GENERATED_NAMES if os.path.isfile(os.path.join(folder, name))]
    for split in ("train", "test"):
        images = os.path.join(folder, split)
        if os.path.isdir(images):
            found += [f"{split}/{name}" for name in sorted(os.listdir(images))
                      if re.fullmatch(r"r_\d+\.png", name)]
    return found


def _replace_folder(partial: str, out: str, overwrite: bool) -> None:
    """Move the finished ``partial`` to ``out``. Over an earlier dataset, its generated files
    are replaced file by file; files the generator did not write (a user's notes, hand-made
    masks) stay."""
    _check_target(out, overwrite)  # the run took minutes: look again before deleting
    new_files = _generated_files(partial)
    if not os.path.lexists(out) or _is_empty_folder(out):
        os.replace(partial, out)  # over an empty folder, too
        Manifest(out, new_files, KIND).save()   # the manifest names the folder it is in
        return
    Manifest(out, _generated_files(out)).remove_written()
    for name in new_files:
        target = os.path.join(out, name)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        os.replace(os.path.join(partial, name), target)
    Manifest(out, new_files, KIND).save()
    shutil.rmtree(partial)


def _record_files(folder: str) -> None:
    """Record every file of the finished staging folder in its manifest."""
    manifest = Manifest(folder, kind=KIND)
    for root, _, names in os.walk(folder):
        manifest.add(*(os.path.join(root, name) for name in names))
    manifest.save()


def generate_dataset(name: str, out: str, settings: GeneratorSettings = GeneratorSettings(),
                     overwrite: bool = False, progress: bool = True) -> dict:
    """Build, render and write one object's dataset into ``out``; returns the run summary.

    Raises FileExistsError (before any work) when ``out`` exists and is not replaceable:
    see :func:`check_output_folder`.
    """
    settings.validate()
    check_output_folder(out, overwrite)
    require_mitsuba()
    parent, folder_name = os.path.split(os.path.normpath(os.path.abspath(out)))
    with folder_lock(parent, f".{folder_name}.generate.lock", "generator", "dataset folder"):
        check_output_folder(out, overwrite)   # the run that held the lock may have made it
        return _generate(name, out, settings, overwrite, progress)


def _generate(name: str, out: str, settings: GeneratorSettings, overwrite: bool,
              progress: bool) -> dict:
    """:func:`generate_dataset` once the folder's lock is held."""
    started = time.perf_counter()
    obj = build_object(name, settings.resolution, settings.seed)
    mesh_seconds = time.perf_counter() - started
    scene = build_scene(obj)
    partial = partial_folder(out)
    if os.path.lexists(partial):
        shutil.rmtree(partial)  # an interrupted run's staging folder (checked above)
    try:
        try:
            writer.ensure_dir(partial)
            writer.write_json(os.path.join(partial, PARTIAL_MARKER), {"object": name})
        except OSError as error:
            raise OutputFolderError("--out", f"'{partial}' cannot be created "
                                             f"({error.strerror or error})") from None
        train_poses, test_poses = sphere_poses(settings.n_train, settings.n_test, settings.seed)
        render_started = time.perf_counter()
        views = [("train", i, pose) for i, pose in enumerate(train_poses)]
        views += [("test", i, pose) for i, pose in enumerate(test_poses)]
        for number, (split, index, pose) in enumerate(
                tqdm(views, desc=f"render {name}", unit="view", disable=not progress)):
            image = render_view(scene, pose, NERF_CAMERA_ANGLE_X, settings.width,
                                settings.height, settings.spp,
                                seed=settings.view_seed(number))
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
        writer.write_json(os.path.join(partial, GENERATOR_FILE), summary)
        os.remove(os.path.join(partial, PARTIAL_MARKER))
        _record_files(partial)
        _replace_folder(partial, out, overwrite)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return summary
