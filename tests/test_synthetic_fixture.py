"""The shipped synthetic fixture (rendered by the generator, see tests/data/synthetic_fixture/
README.md): cameras and images agree with the ground-truth mesh; no Mitsuba needed."""
import json
import os

import numpy as np
import trimesh

from fracture_gs.data import load_dataset
from fracture_gs.data.parts import assign_part_ids, load_part_spec
from synthetic_checks import silhouette_ious

FIXTURE = os.path.join(os.path.dirname(__file__), "data", "synthetic_fixture")


def test_masks_match_ray_cast_mesh_silhouettes():
    ious = silhouette_ious(FIXTURE, split="all")
    assert len(ious) >= 4
    assert min(ious) >= 0.98, ious


def test_a_shifted_camera_breaks_the_agreement():
    """The IoU check is sensitive: moving the mesh by 3% of its size drops it below 0.98."""
    dataset = load_dataset(FIXTURE, split="train")
    mesh = trimesh.load(os.path.join(FIXTURE, "gt_mesh.ply"), process=False)
    import torch

    from fracture_gs.data.synthetic.silhouette import mask_iou, rasterize_silhouette
    camera, mask = dataset.cameras[0], dataset.masks[0].numpy() > 0.5
    shifted = torch.as_tensor(mesh.vertices + np.array([0.03, 0.0, 0.03]))
    uv, _ = camera.project(shifted)
    assert mask_iou(mask, rasterize_silhouette(uv.numpy(), mesh.faces, camera.width,
                                               camera.height)) < 0.98


def test_fixture_layout_and_parts():
    for name in ("transforms_train.json", "transforms_test.json", "gt_mesh.ply", "parts.json"):
        assert os.path.isfile(os.path.join(FIXTURE, name))
    with open(os.path.join(FIXTURE, "transforms_train.json")) as handle:
        transforms = json.load(handle)
    assert transforms["frames"][0]["file_path"] == "./train/r_0"
    dataset = load_dataset(FIXTURE, split="train", white_background=True)
    assert dataset.masks is not None
    # White background: pixels outside the mask are white.
    outside = dataset.masks < 0.01
    assert float(dataset.images[outside].min()) > 0.99
    mesh = trimesh.load(os.path.join(FIXTURE, "gt_mesh.ply"), process=False)
    assert mesh.is_watertight
    assert np.linalg.norm(mesh.vertices, axis=1).max() <= 1.0 + 1e-6
    spec = load_part_spec(os.path.join(FIXTURE, "parts.json"))
    assert set(assign_part_ids(mesh.vertices, spec)) == {0}
