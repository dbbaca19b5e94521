"""Synthetic objects without Mitsuba: teapot data, meshing, watertightness, normalisation,
parts, textures and camera conventions."""
import math

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from fracture_gs.data.parts import assign_part_ids
from fracture_gs.data.synthetic import cameras, shapes, teapot
from fracture_gs.data.synthetic.meshing import connected_component_count
from fracture_gs.data.synthetic.objects import OBJECT_NAMES, build_object
from fracture_gs.data.synthetic.textures import linear_to_srgb
from fracture_gs.data.synthetic.silhouette import mask_iou, rasterize_silhouette
from fracture_gs.render.camera import Camera

GRID = 64  # small marching-cubes resolution keeps these tests fast


@pytest.fixture(scope="module")
def objects():
    return {name: build_object(name, GRID) for name in OBJECT_NAMES}


def test_teapot_table_facts():
    assert teapot.TEAPOT_PATCHES.shape == (32, 16)
    assert teapot.TEAPOT_CONTROL_POINTS.shape == (306, 3)
    assert teapot.TEAPOT_PATCHES.min() == 0 and teapot.TEAPOT_PATCHES.max() == 305
    points = {tuple(p) for p in teapot.TEAPOT_CONTROL_POINTS}
    # The teapot is mirror-symmetric about the xz plane.
    assert all((x, -y if y else y, z) in points for x, y, z in points)
    lower, upper = teapot.TEAPOT_CONTROL_POINTS.min(0), teapot.TEAPOT_CONTROL_POINTS.max(0)
    assert np.allclose(lower, [-3.0, -2.0, 0.0]) and np.allclose(upper, [3.525, 2.0, 3.15])


def test_bezier_patch_interpolates_corners_and_neighbours_share_edges():
    t = np.linspace(0, 1, 5)
    for patch in range(32):
        controls = teapot.patch_controls(patch)
        points, _, _ = teapot.evaluate_patch(controls, t, t)
        for (a, b), (i, j) in {(0, 0): (0, 0), (0, 3): (0, 4), (3, 0): (4, 0),
                               (3, 3): (4, 4)}.items():
            assert np.allclose(points[i, j], controls[a, b])
    # Body patch 5 starts where rim patch 1 ends (shared boundary curve).
    rim, _, _ = teapot.evaluate_patch(teapot.patch_controls(0), [1.0], t)
    body, _, _ = teapot.evaluate_patch(teapot.patch_controls(4), [0.0], t)
    assert np.allclose(rim, body)


def test_caps_close_the_teapot():
    caps = teapot.closing_caps(16)
    assert len(caps) == 5
    annulus_vertices, _ = caps[0]
    radius = np.hypot(annulus_vertices[:, 0], annulus_vertices[:, 1])
    assert np.allclose(annulus_vertices[:, 2], 2.4)
    assert radius.min() > 1.29 and radius.max() < 1.41


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_meshes_watertight_and_normalised(objects, name):
    obj = objects[name]
    mesh = obj.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert radius.max() == pytest.approx(1.0, abs=1e-9)
    assert np.allclose(0.5 * (mesh.bounds[0] + mesh.bounds[1]), 0.0, atol=1e-9)
    # z is up: every object rests on its lowest point with its base wider than a point.
    assert np.sum(mesh.vertices[:, 2] < mesh.bounds[0, 2] + 0.02) > 3


def test_single_pieces():
    for name in ("teapot", "bowl", "table"):
        assert connected_component_count(build_object(name, 48).mesh) == 1


def test_teapot_surface_matches_patches(objects):
    """The solid's surface follows the Bézier patches: outside patch points are on the mesh."""
    obj = objects["teapot"]
    vertices, faces = teapot.tessellate_patches(6)
    samples = (vertices - obj.center) * obj.scale
    surface, _ = trimesh.sample.sample_surface(obj.mesh, 200_000, seed=0)
    distance, _ = cKDTree(surface).query(samples[::3])
    spacing = obj.scale * (3.525 + 3.0) / GRID
    # Most patch points are on the visible surface; a few are buried (handle/spout ends).
    assert np.median(distance) < 0.25 * spacing
    assert np.mean(distance < spacing) > 0.85


def test_parts_assigned_as_designed(objects):
    table = objects["table"]
    top = table.face_parts == 0
    z = table.mesh.triangles_center[:, 2]
    assert top.any() and (~top).any()
    assert z[top].min() > z[~top].min() + 0.5          # legs reach the floor, the top does not
    assert set(np.unique(objects["ficus"].face_parts)) == {0, 1, 2}
    ficus = objects["ficus"]
    zf = ficus.mesh.triangles_center[:, 2]
    assert zf[ficus.face_parts == 0].max() < zf[ficus.face_parts == 2].min()  # pot below leaves
    assert np.all(objects["teapot"].face_parts == 0) and np.all(objects["bowl"].face_parts == 0)
    # The stored (normalised) spec reproduces the labels from the natural-unit recipe.
    natural = ficus.natural_points(ficus.mesh.triangles_center)
    assert np.mean(assign_part_ids(natural, shapes.FICUS_PARTS) == ficus.face_parts) > 0.999


@pytest.mark.parametrize("name", ["table", "ficus"])
def test_part_rules_survive_a_reconstruction_sized_surface_error(objects, name):
    """train.py assigns part_id from parts.json at reconstructed positions, a few millimetres off
    the true surface (the aim is >= 99 % agreement with the part at the nearest true surface
    point). A rule plane lying on a large face (the table's underside) flips that whole face;
    the planes sit in thin sections instead, so moving every surface point 5 mm (natural units)
    along its normal, in or out, changes almost no label."""
    obj = objects[name]
    points, face = trimesh.sample.sample_surface_even(obj.mesh, 20000, seed=1)
    normals = obj.mesh.face_normals[face]
    labels = assign_part_ids(points, obj.part_spec)
    for sign in (1.0, -1.0):
        moved = assign_part_ids(points + sign * 0.005 * obj.scale * normals, obj.part_spec)
        assert np.mean(moved == labels) >= 0.995, (name, sign)


def test_textures_are_valid_and_varied(objects):
    for obj in objects.values():
        for piece in obj.pieces():
            assert piece.colors.shape == (len(piece.vertices), 3)
            assert np.all((piece.colors >= 0) & (piece.colors <= 1))
            srgb = linear_to_srgb(piece.colors)
            assert srgb.std(axis=0).max() > 0.02  # a texture, not a flat colour


def test_camera_poses_opengl_convention():
    train, test = cameras.sphere_poses(20, 5, seed=3)
    assert len(train) == 20 and len(test) == 5
    for pose in train + test:
        rotation = pose[:3, :3]
        assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        eye = pose[:3, 3]
        assert np.linalg.norm(eye) == pytest.approx(cameras.CAMERA_DISTANCE)
        assert np.allclose(-rotation[:, 2], -eye / np.linalg.norm(eye))  # looks at the origin
        assert rotation[2, 1] > 0  # image up has a positive world-z component
    # OpenCV conversion: the origin projects to the image centre, world up is image up.
    w2c = cameras.opengl_to_opencv_world_to_camera(train[0])
    camera = Camera.from_fov(torch.tensor(w2c), cameras.NERF_CAMERA_ANGLE_X, 100, 100)
    uv, depth = camera.project(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3]]))
    assert torch.allclose(uv[0], torch.tensor([50.0, 50.0]), atol=1e-4)
    assert depth[0] == pytest.approx(cameras.CAMERA_DISTANCE, rel=1e-5)
    assert uv[1, 1] < uv[0, 1]


def test_rasterized_silhouette_of_a_square():
    pixels = np.array([[2.0, 2.0], [6.0, 2.0], [6.0, 6.0], [2.0, 6.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    mask = rasterize_silhouette(pixels, faces, 10, 8)
    expected = np.zeros((8, 10), dtype=bool)
    expected[2:6, 2:6] = True  # pixel centres 2.5 .. 5.5
    assert np.array_equal(mask, expected)
    assert mask_iou(mask, expected) == 1.0


def test_rasterized_silhouette_matches_analytic_disc():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    camera = Camera.look_at([0.0, -4.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, 64, 48)
    uv, _ = camera.project(torch.tensor(sphere.vertices, dtype=torch.float32))
    mask = rasterize_silhouette(uv.numpy().astype(np.float64), sphere.faces, 64, 48)
    jj, ii = np.mgrid[0:48, 0:64] + 0.5
    radius_pixels = camera.fx * math.tan(math.asin(1.0 / 4.0))
    disc = (ii - 32) ** 2 + (jj - 24) ** 2 < radius_pixels ** 2
    assert mask_iou(mask, disc) > 0.97


def test_png_conversion_straight_alpha_white_background():
    from fracture_gs.data.synthetic.writer import rgba8_from_premultiplied
    image = np.zeros((1, 3, 4), dtype=np.float32)
    image[0, 0] = [0.5, 0.0, 0.0, 0.5]   # half-covered pure red (premultiplied)
    image[0, 1] = [0.0, 0.0, 0.0, 0.0]   # background
    image[0, 2] = [0.2140, 0.2140, 0.2140, 1.0]  # linear 0.214 ~ sRGB 0.5
    rgba = rgba8_from_premultiplied(image)
    assert rgba[0, 0].tolist() == [255, 0, 0, 128]
    assert rgba[0, 1].tolist() == [255, 255, 255, 0]
    assert abs(int(rgba[0, 2, 0]) - 128) <= 1 and rgba[0, 2, 3] == 255


def test_cli_errors_are_one_line(tmp_path, capsys):
    from fracture_gs.data.synthetic.__main__ import main
    existing = tmp_path / "teapot"
    existing.mkdir()
    assert main(["--object", "teapot", "--out", str(existing)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: ") and "already exists" in error and "\n" not in error
    assert main(["--object", "teapot", "--out", str(tmp_path / "x"), "--width", "0"]) == 2
    assert "--width" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--object", "vase", "--out", str(tmp_path / "y")])
