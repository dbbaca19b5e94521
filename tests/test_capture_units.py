"""The pieces a real capture needs, one by one: nerfstudio intrinsics in the Blender layout, the
hold-out rules, the up direction of level cameras, the cut of the unseen underside, object.json,
scene placement, the model folder's lock and the render background."""
from __future__ import annotations

import json
import math
import threading
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from data_scenes import KNOWN_POINTS, rig, write_blender, write_colmap
from fracture_gs.config.placement import place, rotation_onto_z, upright_rotation
from fracture_gs.config.scene import SceneError, parse_scene
from fracture_gs.data import DatasetError, load_dataset
from fracture_gs.data.loading import has_test_split
from fracture_gs.data.up import camera_up, level_residual_deg
from fracture_gs.folders.model_folder import run_lock, write_cfg_args
from fracture_gs.io.lock import FolderBusy, folder_lock
from fracture_gs.io.object_frame import measure_object, read_object_frame, write_object_frame
from fracture_gs.io.particles_ply import write_particles_ply
from fracture_gs.metrics.halo import halo
from fracture_gs.mpm.scene import build_scene, rotation_matrix_xyz
from fracture_gs.pipeline.background import training_background
from fracture_gs.recon.grid import VoxelGrid
from fracture_gs.recon.support import cut_sdf, support_cut
from fracture_gs.render.camera import Camera


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def edit_json(path: Path, edit) -> None:
    content = json.loads(path.read_text())
    edit(content)
    path.write_text(json.dumps(content))


# ----------------------------------------------------------------------------- Blender intrinsics


@pytest.mark.parametrize("per_frame", [False, True])
def test_blender_layout_reads_a_principal_point_and_focal_lengths(tmp_path: Path,
                                                                  per_frame: bool) -> None:
    """nerfstudio's transforms.json fields: fl_x, fl_y, cx, cy (pixels, centre of the top-left
    pixel at 0.5), in the file or per frame."""
    cameras = rig(3, cx_offset=1.3, fy_ratio=1.1)
    write_blender(str(tmp_path), cameras)

    def intrinsics(content: dict) -> None:
        content.pop("camera_angle_x")
        for frame, camera in zip(content["frames"], cameras):
            target = frame if per_frame else content
            target.update(fl_x=camera.fx, fl_y=camera.fy, cx=camera.cx, cy=camera.cy,
                          w=camera.width, h=camera.height, k1=0.0, p2=0.0)
            if not per_frame:
                break
    if not per_frame:   # one shared camera: give every view the first one's intrinsics
        cameras = [Camera(c.world_to_camera, cameras[0].fx, cameras[0].fy, cameras[0].cx,
                          cameras[0].cy, c.width, c.height) for c in cameras]
    edit_json(tmp_path / "transforms_train.json", intrinsics)
    loaded = load_dataset(str(tmp_path))
    for camera, expected in zip(loaded.cameras, cameras):
        uv, _ = camera.project(KNOWN_POINTS)
        torch.testing.assert_close(uv, expected.project(KNOWN_POINTS)[0], atol=1e-3, rtol=0)


def test_blender_intrinsics_errors_name_the_file_and_field(tmp_path: Path) -> None:
    write_blender(str(tmp_path), rig(2))
    path = tmp_path / "transforms_train.json"
    cases = [(lambda c: c.update(w=41), "'w' is 41"),
             (lambda c: c.update(k1=0.1), "distortion"),
             (lambda c: c.update(cx="a"), "'cx' is not a finite number"),
             (lambda c: (c.pop("camera_angle_x"), c.update(fl_x=-3.0)), "must be > 0")]
    original = path.read_text()
    for edit, needle in cases:
        path.write_text(original)
        edit_json(path, edit)
        with pytest.raises(DatasetError) as info:
            load_dataset(str(tmp_path))
        assert "transforms_train.json" in str(info.value) and needle in str(info.value)


def test_hold_out_applies_to_colmap_and_dtu_not_to_blender(tmp_path: Path) -> None:
    write_blender(str(tmp_path / "blender"), rig(2))
    with pytest.raises(DatasetError, match="own test split"):
        load_dataset(str(tmp_path / "blender"), holdout_every=4)
    assert not has_test_split(str(tmp_path / "blender"))
    write_blender(str(tmp_path / "blender"), rig(1), "test")
    assert has_test_split(str(tmp_path / "blender"))
    write_colmap(str(tmp_path / "colmap"), rig(4))
    assert not has_test_split(str(tmp_path / "colmap"))
    assert has_test_split(str(tmp_path / "colmap"), 2)
    with pytest.raises(DatasetError, match="--holdout-every"):
        load_dataset(str(tmp_path / "colmap"), "test")


# ----------------------------------------------------------------------------- up direction


def level_cameras(up: np.ndarray, count: int, spread_deg: float) -> list[Camera]:
    """Level cameras looking at the origin from azimuths 0..spread_deg, 30-60 deg above it."""
    up = up / np.linalg.norm(up)
    side = np.cross(up, [0.3, 0.5, 0.8])
    side /= np.linalg.norm(side)
    other = np.cross(up, side)
    cameras = []
    for index in range(count):
        azimuth = math.radians(spread_deg * index / max(count - 1, 1))
        elevation = math.radians(30 + 30 * (index % 3) / 2)
        eye = 3 * (math.cos(elevation) * (math.cos(azimuth) * side + math.sin(azimuth) * other)
                   + math.sin(elevation) * up)
        cameras.append(Camera.look_at(eye.tolist(), [0, 0, 0], up.tolist(), math.radians(50),
                                      40, 30))
    return cameras


@pytest.mark.parametrize("spread_deg", [360.0, 120.0])
def test_level_cameras_give_the_world_up(spread_deg: float) -> None:
    up = np.array([0.2, -0.5, -0.8])
    estimate, method = camera_up(level_cameras(up, 9, spread_deg))
    assert method == "level cameras"
    assert angle_deg(estimate, up) < 1e-3
    assert level_residual_deg(level_cameras(up, 9, spread_deg), estimate) < 1e-3


def test_cameras_facing_one_way_fall_back_to_their_mean_up() -> None:
    up = np.array([0.0, 0.0, 1.0])
    cameras = level_cameras(up, 3, 0.0)
    estimate, method = camera_up(cameras)
    assert method == "mean camera up"     # the views tilt it toward the object: only roughly up
    right, _ = (camera.world_to_camera[0, :3].double().numpy() for camera in cameras[:2])
    assert abs(estimate @ right) < 1e-6 and estimate @ up > 0.5


# ----------------------------------------------------------------------------- the unseen underside


def sphere_sdf(voxel: float = 0.05) -> tuple[VoxelGrid, torch.Tensor]:
    grid = VoxelGrid.around(np.full(3, -1.2), np.full(3, 1.2), int(round(2.4 / voxel)))
    return grid, grid.node_positions(dtype=torch.float64).norm(dim=-1).float() - 1.0


@pytest.mark.parametrize("from_below", [False, True])
def test_the_underside_no_camera_sees_is_cut_flat(from_below: bool) -> None:
    """A unit sphere seen from 4 radii away, 20-60 degrees above it: the lowest point the
    cameras see lies 75.5 degrees from the lowest camera's direction (cos = 1/4), at
    z = sin(20 - 75.5 deg) = -0.82, or a little higher through the facing margin; seen from
    below as well, nothing is cut."""
    up = np.array([0.0, 0.0, 1.0])
    cameras = []
    for elevation in ((20.0, 40.0, 60.0) + ((-40.0,) if from_below else ())):
        for azimuth in range(0, 360, 45):
            a, e = math.radians(azimuth), math.radians(elevation)
            eye = 4 * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
            cameras.append(Camera.look_at(eye.tolist(), [0, 0, 0], up.tolist(), math.radians(45),
                                          120, 120))
    grid, sdf = sphere_sdf()
    mesh = trimesh.creation.icosphere(subdivisions=5)
    cut = support_cut(mesh, cameras, up, grid.voxel)
    if from_below:
        assert cut is None
        return
    assert cut is not None and -0.83 < cut.height < -0.65 and cut.depth > 0.15
    cut_field = cut_sdf(sdf, grid, cut)
    nodes = grid.node_positions(dtype=torch.float64)
    inside = cut_field < 0
    assert nodes[inside][:, 2].min() >= cut.height - 1e-6
    above = nodes[..., 2] > cut.height + grid.voxel   # the surface there is the sphere's
    assert torch.equal(cut_field[above] < 0, sdf[above] < 0)
    assert torch.equal(cut_field[above & (sdf > 0)], sdf[above & (sdf > 0)])


# ----------------------------------------------------------------------------- object.json


def test_object_frame_measures_and_round_trips(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform([-2, -0.5, 0], [2, 0.5, 1], size=(2000, 3))   # 4 x 1 x 1 box, z up
    frame = measure_object(points, np.array([0, 0, 2.0]), "--up")
    assert frame.up == (0.0, 0.0, 1.0) and frame.height == pytest.approx(1, abs=0.01)
    assert frame.footprint == pytest.approx((4, 1), abs=0.02)
    assert frame.bottom[2] == pytest.approx(0, abs=0.01)
    write_object_frame(tmp_path / "object.json", frame)
    assert read_object_frame(tmp_path / "object.json") == frame
    edit_json(tmp_path / "object.json", lambda c: c.update(up=[0, 0]))
    with pytest.raises(ValueError, match="'up' is not a list of 3 finite numbers"):
        read_object_frame(tmp_path / "object.json")


# ----------------------------------------------------------------------------- placement


def test_rotation_onto_z_and_the_upright_heading() -> None:
    for up in ([0.3, -0.4, -0.8], [0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0]):
        rotation = rotation_onto_z(np.array(up))
        assert np.allclose(rotation @ np.array(up) / np.linalg.norm(up), [0, 0, 1], atol=1e-12)
        assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1)
    rng = np.random.default_rng(1)
    points = rng.normal(size=(3000, 3)) * [0.2, 3.0, 1.0]   # longest along y, up along z
    rotation = upright_rotation(points, np.array([0, 0, 1.0]), yaw_deg=0.0)
    assert abs((rotation @ [0, 1.0, 0])[0]) > 0.99       # the long axis now lies along x
    scale, rotate_deg, translate = place(points, rotation, (1.0, 2.0), 0.5, size=2.0)
    placed = scale * points @ rotation_matrix_xyz(rotate_deg).T + translate
    assert np.ptp(placed, axis=0).max() == pytest.approx(2.0)
    assert placed[:, 2].min() == pytest.approx(0.5, abs=1e-6) and placed[:, 2].min() >= 0.5


def model_folder(root: Path, up: list[float] | None) -> Path:
    """A model folder with an upright 0.4 x 0.2 x 0.1 box of particles, lying on its side in
    model coordinates (its up is model -y), and object.json saying so (unless ``up`` is None)."""
    rng = np.random.default_rng(2)
    points = rng.uniform([-0.2, -0.05, -0.1], [0.2, 0.05, 0.1], size=(500, 3))
    write_particles_ply(root / "particles.ply", points, np.full(500, 1e-5), np.zeros(500, bool),
                        0, np.full(500, -1))
    if up is not None:
        write_object_frame(root / "object.json", measure_object(points, np.array(up), "--up"))
    return root


def scene(model: Path, placement: dict, **extra) -> dict:
    return {"name": "placed", "domain": {"min": [0, 0, 0], "max": [2, 2, 2], "grid": 16},
            "boundaries": [{"type": "ground", "height": 0.5}],
            "objects": [{"model": str(model), "placement": placement,
                         "materials": [{"part": 0, "model": "elastic", "E": 1e4, "nu": 0.3,
                                        "density": 1}], **extra}]}


def test_placement_stands_a_model_up_by_its_recorded_up(tmp_path: Path) -> None:
    model = model_folder(tmp_path, [0, -1, 0])
    config = parse_scene(scene(model, {"height": 0.2, "centre": [1.0, 0.9], "yaw_deg": 90}))
    x = build_scene(config).particles.x.double().numpy()
    extent = np.ptp(x, axis=0)
    assert extent[2] == pytest.approx(0.2, rel=1e-4)          # model y (0.1 high) stands along z
    assert extent[1] == pytest.approx(0.8, rel=0.02)          # yaw 90: the long side along y
    assert x[:, 2].min() == pytest.approx(0.5, abs=1e-5)      # on the ground
    assert 0.5 * (x.min(axis=0) + x.max(axis=0))[:2] == pytest.approx([1.0, 0.9], abs=1e-5)
    given = parse_scene(scene(model, {"size": 0.8, "up": [0, 0, 1], "centre": [1, 1],
                                      "bottom": 0.6}))
    rotation = rotation_matrix_xyz(given.objects[0].transform.rotate_deg)
    assert np.allclose(rotation @ [0, 0, 1.0], [0, 0, 1], atol=1e-9)


@pytest.mark.parametrize("placement,extra,problem", [
    ({"centre": [1, 1]}, {"transform": {"scale": 1}}, "either 'transform' or 'placement'"),
    ({"size": 1, "height": 1, "centre": [1, 1]}, {}, "'size' (the longest side) or 'height'"),
    ({"size": 1}, {}, "centre: required key is missing"),
    ({"centre": [1]}, {}, "centre: expected a list of 2 numbers"),
    ({"centre": [1, 1], "size": -1}, {}, "size: -1 is not > 0"),
    ({"centre": [1, 1], "up": [0, 0, 0]}, {}, "up: the up direction must not be"),
    ({"centre": [1, 1], "tilt": 3}, {}, "tilt: unknown key"),
])
def test_placement_errors_name_the_key(tmp_path: Path, placement: dict, extra: dict,
                                       problem: str) -> None:
    model = model_folder(tmp_path, [0, 1, 0])
    with pytest.raises(SceneError) as info:
        parse_scene(scene(model, placement, **extra))
    assert "objects[0]" in str(info.value) and problem in str(info.value)


def test_placement_needs_object_json_or_an_up_and_a_ground_or_a_bottom(tmp_path: Path) -> None:
    model = model_folder(tmp_path, None)
    with pytest.raises(SceneError, match="placement.up: 'model' needs the object.json"):
        parse_scene(scene(model, {"centre": [1, 1]}))
    data = scene(model, {"centre": [1, 1], "up": [0, 1, 0]})
    data["boundaries"] = [{"type": "box"}]
    with pytest.raises(SceneError, match="placement.bottom: 'ground' needs a ground boundary"):
        parse_scene(data)
    data["objects"][0]["placement"]["bottom"] = 0.6
    assert parse_scene(data).objects[0].transform.scale == 1.0
    primitive = scene(model, {"centre": [1, 1]})
    del primitive["objects"][0]["model"]
    primitive["objects"][0]["primitive"] = {"shape": "sphere", "radius": 0.1}
    with pytest.raises(SceneError, match="place a primitive with 'transform'"):
        parse_scene(primitive)


# ----------------------------------------------------------------------------- lock, background


def test_the_model_folder_lock_file_goes_when_the_run_ends(tmp_path: Path) -> None:
    with run_lock(str(tmp_path)):
        assert (tmp_path / ".train.lock").is_file()
        with pytest.raises(FolderBusy):
            with run_lock(str(tmp_path)):
                pass
    assert not (tmp_path / ".train.lock").exists()
    with folder_lock(tmp_path, "other.lock", "tool"):   # every command's lock goes with its run
        pass
    assert not (tmp_path / "other.lock").exists()


def test_a_run_waiting_on_a_removed_lock_file_locks_the_new_one(tmp_path: Path) -> None:
    """The holder removes the file it locked while a second run has it open: the second run
    must not lock the orphaned file (a third run would then lock a new one beside it)."""
    import fcntl

    path = tmp_path / ".train.lock"
    holder = open(path, "a+")
    fcntl.flock(holder, fcntl.LOCK_EX)
    entered = threading.Event()

    def second() -> None:
        for _ in range(200):
            try:
                with run_lock(str(tmp_path)):
                    entered.set()
                    assert path.is_file()
                    with pytest.raises(FolderBusy):   # the file it holds is the one there
                        with run_lock(str(tmp_path)):
                            pass
                return
            except FolderBusy:
                threading.Event().wait(0.01)

    thread = threading.Thread(target=second)
    thread.start()
    path.unlink()          # the holder ends: removes the file, then releases it
    fcntl.flock(holder, fcntl.LOCK_UN)
    holder.close()
    thread.join(10)
    assert entered.is_set() and not path.exists()


def test_render_background_follows_the_training_background(tmp_path: Path) -> None:
    primitive = {"shape": "sphere", "radius": 0.1}
    material = [{"part": 0, "model": "elastic", "E": 1e4, "nu": 0.3, "density": 1}]
    spheres = parse_scene({"name": "s", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
                           "objects": [{"primitive": primitive, "materials": material,
                                        "transform": {"translate": [0.5, 0.5, 0.5]}}]})
    assert training_background(spheres) == "white"
    for white, expected in ((False, "black"), (True, "white")):
        (tmp_path / f"model_{white}").mkdir()
        model = model_folder(tmp_path / f"model_{white}", [0, 1, 0])
        write_cfg_args(str(model / "cfg_args"), {"white_background": white})
        config = parse_scene({"name": "m", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
                              "objects": [{"model": str(model), "materials": material,
                                           "transform": {"translate": [0.5, 0.5, 0.5]}}]})
        assert training_background(config) == expected


def test_halo_counts_pixels_off_the_background_outside_the_dilated_mask() -> None:
    mask = np.zeros((40, 40))
    mask[10:20, 10:20] = 1
    render = np.zeros((40, 40, 3))
    render[10:20, 10:20] = 0.8
    render[21, 10:20] = 0.5          # within 2 px of the mask: forgiven
    render[35, 0:10] = 0.5           # far outside: counted
    render[36, 0:10] = 0.02          # below the threshold
    result = halo(render, mask, (0.0, 0.0, 0.0), dilate_px=2)
    assert result.differing == 10
    assert 40 * 40 - 14 * 14 <= result.outside < 40 * 40 - 10 * 10
    assert result.share == pytest.approx(10 / result.outside)
    assert halo(render, mask, (0.5, 0.5, 0.5), dilate_px=2).differing > 1000


def test_evaluating_a_model_without_test_views_names_the_hold_out(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    """A COLMAP model trained on every view: evaluate.py -m says how to get a test split."""
    from fracture_gs.cli import evaluate as evaluate_cli
    from fracture_gs.gaussians import GaussianModel, write_ply

    write_colmap(str(tmp_path / "photos"), rig(3), with_masks=True)
    model = tmp_path / "model"
    write_cfg_args(str(model / "cfg_args"), {"source_path": str(tmp_path / "photos"),
                                             "resolution": 1, "white_background": False,
                                             "holdout_every": 0})
    write_ply(str(model / "point_cloud" / "iteration_1" / "point_cloud.ply"),
              GaussianModel.from_points(torch.zeros(4, 3), sh_degree=0))
    assert evaluate_cli.main(["-m", str(model), "--no-lpips", "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--holdout-every N" in err
