"""Tests that render with Mitsuba 3 (skipped when it is not installed, failed when CI=true:
see tests/conftest.py)."""
import json
import os

import numpy as np
import pytest
import torch
import trimesh

from fracture_gs.data.parts import single_part_spec
from fracture_gs.data.synthetic import cameras, render_mitsuba
from fracture_gs.data.synthetic.generator import GeneratorSettings, generate_dataset
from fracture_gs.data.synthetic.objects import PartLook, SyntheticObject
from fracture_gs.data.synthetic.silhouette import mask_iou, rasterize_silhouette
from fracture_gs.render.camera import Camera
from synthetic_checks import silhouette_ious

pytestmark = pytest.mark.mitsuba


def _sphere_object(center, radius):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    sphere.apply_translation(center)
    look = PartLook(lambda p: np.full((len(p), 3), 0.5), 0.5, 0.5)
    return SyntheticObject("sphere", sphere, single_part_spec(), np.zeros(len(sphere.faces),
                           dtype=np.int32), np.zeros(3), 1.0, (look,), "test sphere")


def test_mitsuba_camera_frame_matches_opencv_projection():
    """An off-centre sphere appears where Camera.project puts it: image x right, y down."""
    center = np.array([0.5, 0.2, 0.35])
    obj = _sphere_object(center, 0.15)
    scene = render_mitsuba.build_scene(obj)
    width, height = 80, 60
    for eye in ([0.3, -4.0, 0.8], [3.0, 2.0, -1.5]):
        pose = cameras.look_at_opengl(np.array(eye))
        image = render_mitsuba.render_view(scene, pose, 0.7, width, height, spp=16)
        alpha = image[..., 3]
        w2c = torch.tensor(cameras.opengl_to_opencv_world_to_camera(pose))
        camera = Camera.from_fov(w2c, 0.7, width, height)
        uv, _ = camera.project(torch.tensor(obj.mesh.vertices))
        silhouette = rasterize_silhouette(uv.numpy().astype(np.float64), obj.mesh.faces,
                                          width, height)
        assert mask_iou(alpha > 0.5, silhouette) > 0.95
        rows, cols = np.nonzero(alpha > 0.5)
        centre_uv = camera.project(torch.tensor(center[None]))[0][0].numpy()
        assert abs(cols.mean() + 0.5 - centre_uv[0]) < 1.0
        assert abs(rows.mean() + 0.5 - centre_uv[1]) < 1.0


def test_generate_small_dataset_end_to_end(tmp_path):
    out = str(tmp_path / "teapot")
    settings = GeneratorSettings(width=48, height=48, n_train=2, n_test=1, spp=4, seed=1,
                                 resolution=32)
    summary = generate_dataset("teapot", out, settings, progress=False)
    assert summary["watertight"]
    assert not os.path.exists(out + ".partial")
    with open(os.path.join(out, "transforms_test.json")) as handle:
        assert len(json.load(handle)["frames"]) == 1
    assert min(silhouette_ious(out)) >= 0.95  # tiny images: boundary pixels weigh more
    with pytest.raises(FileExistsError, match="already exists"):
        generate_dataset("teapot", out, settings, progress=False)
    # --force replaces a dataset the generator wrote, leaves none of its files behind and keeps
    # the files it did not write
    first = json.loads((tmp_path / "teapot" / "generator.json").read_text())
    (tmp_path / "teapot" / "notes.txt").write_text("a user's file")
    again = GeneratorSettings(width=40, height=40, n_train=1, n_test=1, spp=4, seed=2,
                              resolution=32)
    generate_dataset("teapot", out, again, overwrite=True, progress=False)
    assert json.loads((tmp_path / "teapot" / "generator.json").read_text())["settings"]["seed"] == 2
    assert first["settings"]["seed"] == 1
    assert not (tmp_path / "teapot" / "train" / "r_1.png").exists()   # the first run's 2nd view
    assert (tmp_path / "teapot" / "notes.txt").read_text() == "a user's file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["teapot"]   # no .partial / .replaced
