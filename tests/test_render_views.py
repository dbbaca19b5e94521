"""View specs (orbit:N, cameras.json, dataset cameras moved by the object transform) and the
simulation folder reader's frame selection."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from fracture_gs.mpm.scene import rotation_matrix_xyz
from fracture_gs.render import Camera
from fracture_gs.render.views import (ViewSpecError, cameras_from_json, orbit_views,
                                      transform_camera)
from fracture_gs.folders.sim_reader import Simulation, SimulationError
from render_scenes import block_scene, identity_frames, lattice_block, write_sim


def test_orbit_cameras_circle_the_centre_and_frame_the_sphere():
    centre, radius = np.array([0.4, 0.5, 0.3]), 0.2
    views = orbit_views(6, centre, radius, 120, 90, up=(0, 0, 1))
    assert [v.name for v in views] == [f"orbit_{i:02d}" for i in range(6)]
    eyes = torch.stack([v.camera.center for v in views]).double().numpy()
    distances = np.linalg.norm(eyes - centre, axis=1)
    assert np.allclose(distances, distances[0], rtol=1e-5)
    heights = eyes[:, 2] - centre[2]
    assert np.allclose(heights, distances * math.sin(math.radians(20.0)), rtol=1e-4)
    angles = np.unwrap(np.arctan2(eyes[:, 1] - centre[1], eyes[:, 0] - centre[0]))
    assert np.allclose(np.diff(angles), 2 * math.pi / 6, atol=1e-5)
    # the centre projects to the image centre, the bounding sphere stays inside the image
    sphere = centre + radius * np.concatenate([np.eye(3), -np.eye(3)])
    for view in views:
        uv, depth = view.camera.project(torch.tensor(np.vstack([centre, sphere]), dtype=torch.float32))
        assert torch.allclose(uv[0], torch.tensor([60.0, 45.0]), atol=1e-3)
        assert (depth > 0).all()
        assert (uv[:, 0] > 0).all() and (uv[:, 0] < 120).all()
        assert (uv[:, 1] > 0).all() and (uv[:, 1] < 90).all()


def test_cameras_json_round_trip(tmp_path: Path):
    camera = Camera.look_at([1.0, -2.0, 0.5], [0.0, 0.1, 0.0], [0, 0, 1], 0.9, 64, 48)
    c2w = camera.camera_to_world.double().numpy()
    entries = [{"id": 0, "img_name": "r_0", "width": 64, "height": 48,
                "position": c2w[:3, 3].tolist(), "rotation": c2w[:3, :3].tolist(),
                "fx": camera.fx, "fy": camera.fy}]
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(entries))
    views = cameras_from_json(path)
    assert views[0].name == "r_0"
    assert torch.allclose(views[0].camera.world_to_camera, camera.world_to_camera, atol=1e-5)
    half = cameras_from_json(path, size=(32, 24))[0].camera
    assert (half.width, half.height) == (32, 24) and half.fx == pytest.approx(camera.fx / 2)
    path.write_text("[{\"id\": 0}]")
    with pytest.raises(ViewSpecError, match="cameras.json: camera 0 lacks"):
        cameras_from_json(path)


def test_transform_camera_sees_the_moved_object_like_the_original():
    camera = Camera.look_at([0.0, -3.0, 1.0], [0, 0, 0], [0, 0, 1], 0.8, 50, 40)
    rotation = rotation_matrix_xyz((10.0, 25.0, -40.0))
    scale, translate = 0.4, np.array([0.5, 0.6, 0.2])
    moved = transform_camera(camera, rotation, scale, translate)
    points = torch.rand(20, 3) - 0.5
    world = torch.tensor(translate + scale * points.double().numpy() @ rotation.T, dtype=torch.float32)
    uv, depth = camera.project(points)
    uv_moved, depth_moved = moved.project(world)
    assert torch.allclose(uv, uv_moved, atol=1e-3)
    assert torch.allclose(depth * scale, depth_moved, rtol=1e-5)


@pytest.fixture()
def three_frames(tmp_path: Path) -> Simulation:
    points, surface = lattice_block((0.04, 0.04, 0.04))
    count = points.shape[0]
    rest = points + 0.5
    arrays = {"rest_x": rest.astype(np.float32), "obj_id": np.zeros(count, np.int32),
              "is_surface": surface, "gaussian_index": np.full(count, -1),
              "rest_volume": np.full(count, 8e-6, np.float32)}
    return Simulation.open(write_sim(tmp_path / "sim", block_scene(None), arrays,
                                     identity_frames(rest, 3)))


def test_frame_selection(three_frames: Simulation):
    sim = three_frames
    assert sim.select_frames(None) == [0, 1, 2]
    assert sim.select_frames("1:") == [1, 2]
    assert sim.select_frames(":2") == [0, 1]
    assert sim.select_frames("0:3") == [0, 1, 2]
    assert sim.select_frames("2") == [2]
    for spec, message in (("2:9", "outside the run"), ("5", "outside the run"), ("7:", "outside the run"),
                          ("2:1", "empty range"), ("a:b", "expected a, a:b")):
        with pytest.raises(SimulationError, match=message):
            sim.select_frames(spec)
    (sim.root / "frames" / "frame_00001.npz").unlink()
    with pytest.raises(SimulationError, match="frame_00001.npz is missing"):
        Simulation.open(sim.root).select_frames("0:3")


def test_train_and_test_views_are_the_dataset_cameras_moved_with_the_object(tmp_path: Path):
    from fracture_gs.pipeline.views import resolve_views
    from fracture_gs.data import load_dataset
    from render_scenes import write_model

    fixture = Path(__file__).parent / "data" / "synthetic_fixture"
    points, surface = lattice_block((0.04, 0.04, 0.04))
    write_model(tmp_path / "model", points, surface)
    (tmp_path / "model" / "cfg_args").write_text(
        f"Namespace(sh_degree=1, source_path='{fixture}', model_path='{tmp_path / 'model'}')")
    transform = {"scale": 0.3, "rotate_deg": [0.0, 0.0, 40.0], "translate": [0.5, 0.5, 0.4]}
    rest = (np.array(transform["translate"]) + 0.3 * points @ rotation_matrix_xyz((0.0, 0.0, 40.0)).T
            ).astype(np.float32)
    count = points.shape[0]
    arrays = {"rest_x": rest, "obj_id": np.zeros(count, np.int32), "is_surface": surface,
              "gaussian_index": np.where(surface, np.cumsum(surface) - 1, -1),
              "rest_volume": np.full(count, 1e-6, np.float32)}
    sim = Simulation.open(write_sim(tmp_path / "sim", block_scene(tmp_path / "model", transform),
                                    arrays, identity_frames(rest, 1)))
    views = resolve_views("train", sim, sim.frames, None)
    cameras = load_dataset(str(fixture), split="train").cameras
    assert [v.name for v in views] == [f"train_r_{i}" for i in range(len(cameras))]
    # a model-frame point seen by the dataset camera lands on the same pixel in the scene
    model_points = torch.tensor(points[:20], dtype=torch.float32)
    scene_points = torch.tensor(rest[:20])
    for view, camera in zip(views, cameras):
        assert torch.allclose(view.camera.project(scene_points)[0], camera.project(model_points)[0],
                              atol=2e-3)
    assert len(resolve_views("test", sim, sim.frames, (48, 48))) == 1
    (tmp_path / "model" / "cfg_args").write_text("Namespace(sh_degree=1)")
    with pytest.raises(ViewSpecError, match="cfg_args: no source_path"):
        resolve_views("train", sim, sim.frames, None)


def test_frames_read_fragment_ids_when_present(three_frames: Simulation):
    sim = three_frames
    assert sim.load_frame(0).fragment_id is None          # runs without fragment_id have none
    path = sim.frame_path(1)
    with np.load(path) as data:
        arrays = dict(data)
    count = arrays["x"].shape[0]
    labels = np.zeros(count, np.int32)
    labels[count // 2:] = count // 2
    np.savez(path, **arrays, fragment_id=labels)
    loaded = sim.load_frame(1)
    assert loaded.fragment_id.dtype == torch.int64 and loaded.fragment_id.tolist() == labels.tolist()
    assert loaded.to(torch.device("cpu")).fragment_id.tolist() == labels.tolist()
    for bad, message in ((labels[:-1], "shape"), (labels + count, r"labels in \[0, "),
                         (labels.astype(np.float32), r"labels in \[0, ")):
        np.savez(path, **arrays, fragment_id=bad)
        with pytest.raises(SimulationError, match=message):
            sim.load_frame(1)
