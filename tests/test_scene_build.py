"""SceneConfig → particles: primitive sampling, particles.ply models, transforms, materials."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from fracture_gs.config import PrimitiveConfig, SceneError, TransformConfig, parse_scene
from fracture_gs.mpm.scene import (apply_transform, build_scene, load_particles_ply, object_particles,
                                   primitive_signed_distance, rotation_matrix_xyz,
                                   sample_primitive)

NACC = {"model": "nacc", "E": 1e4, "nu": 0.3, "density": 10.0, "alpha0": -0.02}


def write_particles_ply(path: Path, x: np.ndarray, volume: np.ndarray, part_id: np.ndarray,
                        is_surface: np.ndarray | None = None,
                        gaussian_index: np.ndarray | None = None) -> None:
    n = x.shape[0]
    is_surface = np.zeros(n, bool) if is_surface is None else is_surface
    gaussian_index = np.full(n, -1) if gaussian_index is None else gaussian_index
    vertex = np.empty(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("volume", "f4"),
                                ("is_surface", "u1"), ("part_id", "i4"),
                                ("gaussian_index", "i4")])
    vertex["x"], vertex["y"], vertex["z"] = x.T
    vertex["volume"] = volume
    vertex["is_surface"] = is_surface
    vertex["part_id"] = part_id
    vertex["gaussian_index"] = gaussian_index
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(path))


def scene_with(objects: list[dict[str, Any]], **extra: Any) -> dict[str, Any]:
    scene = {"name": "t", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
             "frames": 1, "objects": objects}
    scene.update(extra)
    return scene


@pytest.mark.parametrize("primitive,volume", [
    (PrimitiveConfig("box", size=(0.3, 0.2, 0.25)), 0.3 * 0.2 * 0.25),
    (PrimitiveConfig("sphere", radius=0.15), 4 / 3 * math.pi * 0.15 ** 3),
    (PrimitiveConfig("cylinder", radius=0.1, height=0.3), math.pi * 0.01 * 0.3),
])
def test_primitive_sampling_fills_the_shape(primitive: PrimitiveConfig, volume: float) -> None:
    dx = 1.0 / 32
    sample = sample_primitive(primitive, dx, 1.0, np.random.default_rng(0))
    n = sample.x.shape[0]
    assert np.allclose(sample.rest_volume, dx ** 3 / primitive.particles_per_cell)
    # the particle volumes add up to the shape's volume (jitter noise only)
    assert sample.rest_volume.sum() == pytest.approx(volume, rel=0.03)
    assert (primitive_signed_distance(primitive, sample.x) <= 0).all()
    # centred on the origin, particles_per_cell per grid cell on average
    assert np.abs(sample.x.mean(axis=0)).max() < 0.01
    assert n == pytest.approx(volume / dx ** 3 * primitive.particles_per_cell, rel=0.03)
    # surface flags form a shell one particle spacing thick
    spacing = dx / 2
    d = primitive_signed_distance(primitive, sample.x)
    assert (sample.is_surface == (d > -spacing)).all()
    assert 0 < sample.is_surface.sum() < n
    assert (sample.part_id == 0).all() and (sample.gaussian_index == -1).all()


def test_primitive_sampling_is_deterministic_and_scaled() -> None:
    prim = PrimitiveConfig("sphere", radius=0.1, particles_per_cell=5)
    a = sample_primitive(prim, 0.05, 2.0, np.random.default_rng([3, 0]))
    b = sample_primitive(prim, 0.05, 2.0, np.random.default_rng([3, 0]))
    assert np.array_equal(a.x, b.x)
    assert np.linalg.norm(a.x, axis=1).max() <= 0.2 + 1e-12   # scaled radius
    assert np.allclose(a.rest_volume, 0.05 ** 3 / 5)          # volume per particle fixed by dx


def test_rotation_order_is_extrinsic_xyz() -> None:
    ax, ay, az = 30.0, 45.0, 60.0

    def rot(axis: int, deg: float) -> np.ndarray:
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    expected = rot(2, az) @ rot(1, ay) @ rot(0, ax)
    assert np.allclose(rotation_matrix_xyz((ax, ay, az)), expected)
    # a quarter turn about z takes +x to +y
    moved = apply_transform(np.array([[1.0, 0.0, 0.0]]),
                            TransformConfig(scale=2.0, rotate_deg=(0, 0, 90),
                                            translate=(1, 2, 3)))
    assert np.allclose(moved, [[1.0, 4.0, 3.0]])


def test_particles_ply_reading(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.1, 0.1, (50, 3))
    write_particles_ply(tmp_path / "p.ply", x, np.full(50, 1e-5), np.arange(50) % 2,
                        is_surface=np.arange(50) < 10, gaussian_index=np.where(
                            np.arange(50) < 10, np.arange(50), -1))
    loaded = load_particles_ply(tmp_path / "p.ply")
    assert np.allclose(loaded.x, x, atol=1e-7)
    assert loaded.is_surface.sum() == 10
    assert loaded.gaussian_index[:10].tolist() == list(range(10))
    assert (loaded.gaussian_index[10:] == -1).all()
    assert set(loaded.part_id.tolist()) == {0, 1}


def test_particles_ply_missing_property(tmp_path: Path) -> None:
    vertex = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(tmp_path / "p.ply"))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.model: .*lacks .*'volume'"):
        load_particles_ply(tmp_path / "p.ply", "objects[0].model")


def test_model_object_transform_parts_and_masses(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    x = rng.uniform(-0.05, 0.05, (200, 3))
    part = (x[:, 0] > 0).astype(np.int32)
    model_dir = tmp_path / "rock"
    model_dir.mkdir()
    write_particles_ply(model_dir / "particles.ply", x, np.full(200, 2e-6), part,
                        gaussian_index=np.arange(200))
    config = parse_scene(scene_with([
        {"name": "rock", "model": str(model_dir),
         "transform": {"scale": 2.0, "rotate_deg": [0, 0, 90], "translate": [0.5, 0.5, 0.5]},
         "velocity": [0, 0, -1],
         "materials": [dict(NACC, part=1, density=100.0), dict(NACC, part=0)]},
        {"name": "ball", "primitive": {"shape": "sphere", "radius": 0.08,
                                       "particles_per_cell": 1},
         "transform": {"translate": [0.5, 0.5, 0.72]},
         "materials": [{"model": "elastic", "E": 1e3, "nu": 0.2, "density": 3.0}]},
    ]))
    built = build_scene(config, torch.device("cpu"))
    p = built.particles
    rock = (p.obj_id == 0).numpy()
    assert rock.sum() == 200 and (~rock).sum() > 0
    # build_scene reorders particles (spatial_order); every column travels with its row, so the
    # file's row of each particle is its gaussian_index here.
    row = p.gaussian_index[rock].numpy()
    assert sorted(row) == list(range(200))
    expected_x = 2.0 * (x.astype(np.float32).astype(np.float64) @
                        rotation_matrix_xyz((0, 0, 90)).T) + 0.5
    assert np.allclose(p.x[rock].numpy(), expected_x[row], atol=1e-6)
    assert (p.part_id[rock].numpy() == part[row]).all()
    assert np.allclose(p.rest_volume[rock].numpy(), 2e-6 * 8)        # scale³
    assert np.allclose(p.v[rock].numpy(), [0, 0, -1])
    # one material row per (object, part), in part order per object
    assert built.material_keys == [(0, 0), (0, 1), (1, 0)]
    assert built.object_names == ["rock", "ball"]
    part_np = p.part_id.numpy()
    assert (p.material_id.numpy()[rock] == part_np[rock]).all()
    assert (p.material_id.numpy()[~rock] == 2).all()
    density = np.where(part_np[rock] == 1, 100.0, 10.0)
    assert np.allclose(p.mass[rock].numpy(), density * 2e-6 * 8, rtol=1e-6)
    assert np.allclose(p.mass[~rock].numpy(), 3.0 * p.rest_volume[~rock].numpy())
    assert p.x.dtype == torch.float32 and p.obj_id.dtype == torch.int32
    assert p.gaussian_index.dtype == torch.int64 and p.is_surface.dtype == torch.bool
    assert len(built.materials) == 3


def test_part_without_material_is_an_error(tmp_path: Path) -> None:
    x = np.random.default_rng(3).uniform(-0.05, 0.05, (30, 3))
    write_particles_ply(tmp_path / "two_parts.ply", x, np.full(30, 1e-6), np.arange(30) % 2)
    config = parse_scene(scene_with([
        {"name": "vase", "model": str(tmp_path / "two_parts.ply"),
         "transform": {"translate": [0.5, 0.5, 0.5]}, "materials": [dict(NACC, part=0)]}]))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.materials: part 1 .* no material"):
        build_scene(config)
    config = parse_scene(scene_with([
        {"name": "vase", "model": str(tmp_path / "two_parts.ply"),
         "transform": {"translate": [0.5, 0.5, 0.5]},
         "materials": [dict(NACC, part=0), dict(NACC, part=1), dict(NACC, part=7)]}]))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.materials\[2\]\.part: .* no part 7"):
        build_scene(config)


@pytest.mark.parametrize("translate,boundaries,fragment", [
    ([0.5, 0.5, 0.12], [], "reaches z = "),          # through the floor wall margin
    ([0.95, 0.5, 0.5], [], "reaches x = "),          # past the +x wall
    ([0.5, 0.5, 0.3], [{"type": "ground", "height": 0.25}], "below the ground"),
])
def test_object_outside_domain_is_an_error(translate: list[float], boundaries: list[Any],
                                           fragment: str) -> None:
    config = parse_scene(scene_with([
        {"name": "ball", "primitive": {"shape": "sphere", "radius": 0.1},
         "transform": {"translate": translate}, "materials": [NACC]}],
        boundaries=boundaries))
    with pytest.raises(SceneError) as info:
        build_scene(config)
    assert info.value.key_path == "objects[0].transform"
    assert fragment in info.value.problem


def test_object_inside_margin_is_accepted() -> None:
    # grid 16 → dx = 1/16, margin = 3/16 = 0.1875; a 0.2 box centred at 0.3 spans 0.2..0.4
    config = parse_scene(scene_with([
        {"name": "cube", "primitive": {"shape": "box", "size": [0.2, 0.2, 0.2]},
         "transform": {"translate": [0.3, 0.3, 0.3]}, "materials": [NACC]}]))
    built = build_scene(config)
    assert len(built.particles) == pytest.approx(0.008 * 16 ** 3 * 8, rel=0.05)


def test_overlap_of_model_objects_is_measured_by_their_particles(tmp_path: Path) -> None:
    """A particles.ply model placed twice: fully on top of itself is reported, side by side with
    a gap of one spacing is not; a primitive touching a model is not either."""
    from fracture_gs.mpm.scene import overlap_warnings

    spacing = 0.02
    axis = np.arange(-0.06, 0.06 + 1e-9, spacing)
    x = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    ply = tmp_path / "cube.ply"
    write_particles_ply(ply, x, np.full(len(x), spacing ** 3), np.zeros(len(x), np.int32))

    def model(name: str, centre: list[float]) -> dict[str, Any]:
        return {"name": name, "model": str(ply), "transform": {"translate": centre},
                "materials": [{"part": 0, **NACC}]}

    def warnings(objects: list[dict[str, Any]]) -> list[str]:
        config = parse_scene(scene_with(objects))
        assert list(build_scene(config).warnings) == overlap_warnings(
            config, [object_particles(config, i) for i in range(len(objects))])
        return list(build_scene(config).warnings)

    same, = warnings([model("a", [0.5, 0.5, 0.5]), model("b", [0.5, 0.5, 0.5])])
    assert same.startswith("objects 'a' and 'b' overlap: 100% of the particles of 'a' lie "
                           "inside 'b'")
    half, = warnings([model("a", [0.5, 0.5, 0.5]), model("b", [0.56, 0.5, 0.5])])
    assert "overlap: 57%" in half                    # 4 of the 7 particle layers
    assert warnings([model("a", [0.5, 0.5, 0.5]), model("b", [0.5 + 8 * spacing, 0.5, 0.5])]) == []
    box = {"name": "box", "primitive": {"shape": "box", "size": [0.1, 0.3, 0.3]},
           "transform": {"translate": [0.5 - 0.07 - 0.05 - 0.001, 0.5, 0.5]},
           "materials": [{"part": 0, **NACC}]}
    assert warnings([model("a", [0.5, 0.5, 0.5]), box]) == []


def test_particles_per_cell_and_the_density_warning() -> None:
    """The typical particle's cell count: 8 for a 2x2x2 lattice per cell, Σc²/Σc for uneven
    cells; a primitive sampled far denser than the solver is built for is warned about with the
    finer grid that brings it to the limit, an ordinary one is not."""
    from fracture_gs.mpm.density import MAX_PARTICLES_PER_CELL, grid_for_density, particles_per_cell

    dx = 0.1
    axis = (np.arange(8) + 0.5) * dx / 2  # 2 particles per cell along each of 4 cells
    lattice = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    assert particles_per_cell(lattice, (0, 0, 0), dx) == pytest.approx(8.0)
    uneven = np.concatenate([np.full((30, 3), 0.05), np.full((10, 3), 0.15)])  # cells of 30 and 10
    assert particles_per_cell(uneven, (0, 0, 0), dx) == pytest.approx((30 ** 2 + 10 ** 2) / 40)
    assert grid_for_density(48, 64 * 8, 64) == 96  # 8 times the count per cell: half the cell edge

    def built(per_cell: int):
        return build_scene(parse_scene(scene_with([
            {"name": "dense", "primitive": {"shape": "box", "size": [0.25, 0.25, 0.25],
                                            "particles_per_cell": per_cell},
             "transform": {"translate": [0.5, 0.5, 0.5]}, "materials": [NACC]}])))

    assert built(8).warnings == ()
    warning, = built(216).warnings
    measured = float(warning.split("puts ")[1].split(" particles")[0])
    assert 150 < measured <= 216 and measured > MAX_PARTICLES_PER_CELL
    assert warning.startswith("object 'dense' puts ") and "16-cell grid" in warning
    assert f"domain.grid >= {grid_for_density(16, measured, MAX_PARTICLES_PER_CELL)}" in warning
    assert "particles_per_cell" in warning
