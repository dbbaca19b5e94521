"""Unit checks of the reconstruction stages: grid interpolation, visual hull,
NeuS opacity, meshing, particle sampling and volumes, image metrics."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import trimesh
from scipy import ndimage

from fracture_gs.data.dataset import Dataset
from fracture_gs.metrics.image import psnr, ssim
from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.grid import (VoxelGrid, cell_corners, interpolate, interpolate_gradient,
                                    resample, sample_dense)
from fracture_gs.recon.hull import mask_signed_distance, visual_hull
from fracture_gs.recon.meshing import extract_mesh
from fracture_gs.recon.particles import (distribute_volume, maximal_poisson_disk,
                                         sample_particles, sample_surface_even)
from fracture_gs.recon.quality import chamfer_distance, spacing_variation
from fracture_gs.recon.sdf_refine import composite_weights, neus_alpha
from fracture_gs.render import Camera


def _grid() -> VoxelGrid:
    return VoxelGrid((0.1, -0.2, 0.3), 0.05, (7, 9, 11))


def _points(grid: VoxelGrid, count: int, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    extent = torch.tensor(grid.upper - grid.lower)
    return torch.rand(count, 3, generator=generator, dtype=torch.float64) * extent \
        + torch.tensor(grid.lower)


def test_trilinear_matches_grid_sample_and_reproduces_linear_fields() -> None:
    grid = _grid()
    values = torch.randn(*grid.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    points = _points(grid, 500)
    corners = cell_corners(grid, points)
    assert torch.allclose(interpolate(values.reshape(-1), corners),
                          sample_dense(values, grid, points), atol=1e-12)
    linear = grid.node_positions().double() @ torch.tensor([1.5, -2.0, 0.25], dtype=torch.float64) + 0.3
    assert torch.allclose(interpolate(linear.reshape(-1), corners),
                          points @ torch.tensor([1.5, -2.0, 0.25], dtype=torch.float64) + 0.3)
    gradient = interpolate_gradient(linear.reshape(-1), corners)
    assert torch.allclose(gradient, torch.tensor([[1.5, -2.0, 0.25]], dtype=torch.float64)
                          .expand_as(gradient))


def test_analytic_gradient_equals_autograd_position_gradient() -> None:
    grid = _grid()
    values = torch.randn(grid.num_nodes, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    points = _points(grid, 200, seed=3).requires_grad_(True)
    value = interpolate(values, cell_corners(grid, points))
    (autograd,) = torch.autograd.grad(value.sum(), points)
    assert torch.allclose(interpolate_gradient(values, cell_corners(grid, points.detach())),
                          autograd, atol=1e-10)


def test_resample_to_refined_grid_keeps_node_values() -> None:
    grid = _grid()
    values = torch.randn(*grid.shape, dtype=torch.float64)
    fine = resample(values, grid, grid.refined(2))
    assert torch.allclose(fine[::2, ::2, ::2], values, atol=1e-12)


def test_mask_signed_distance_of_a_disk_is_subpixel_accurate() -> None:
    size, radius = 96, 30.3
    column, row = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    distance = np.hypot(column - 48.2, row - 47.9) - radius
    alpha = np.clip(0.5 - distance, 0.0, 1.0).astype(np.float32)  # anti-aliased edge
    signed = mask_signed_distance(alpha)
    near_edge = np.abs(distance) < 6
    assert np.abs(signed - distance)[near_edge].max() < 0.5
    assert np.abs(signed - distance)[near_edge].mean() < 0.2


def _sphere_dataset(radius: float, views: int, size: int = 64) -> Dataset:
    cameras, masks = [], []
    golden = math.pi * (3 - math.sqrt(5))
    for index in range(views):
        z = 0.9 - 1.6 * (index + 0.5) / views
        ring = math.sqrt(1 - z * z)
        eye = 3.0 * np.array([ring * math.cos(golden * index), ring * math.sin(golden * index), z])
        camera = Camera.look_at(eye, (0, 0, 0), (0, 0, 1), fov_x_rad=0.8, width=size, height=size)
        column, row = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
        # silhouette of a sphere: the cone of rays tangent to it
        direction = np.stack([(column - camera.cx) / camera.fx, (row - camera.cy) / camera.fy,
                              np.ones_like(column)], -1)
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        distance = np.linalg.norm(eye)
        sine = np.sqrt(np.clip(1 - direction[..., 2] ** 2, 0, 1))  # angle off the axis
        angle = np.arcsin(np.clip(sine, 0, 1))
        edge = np.arcsin(radius / distance)
        pixels_per_radian = camera.fx
        masks.append(np.clip(0.5 + (edge - angle) * pixels_per_radian, 0, 1))
        cameras.append(camera)
    images = torch.zeros(views, size, size, 3)
    return Dataset(cameras, images, torch.tensor(np.array(masks), dtype=torch.float32),
                   [f"view{i}.png" for i in range(views)], "blender")


def test_visual_hull_of_a_sphere_approaches_the_sphere() -> None:
    dataset = _sphere_dataset(0.5, views=24)
    hull = visual_hull(dataset, 32, torch.device("cpu"))
    mesh = extract_mesh(hull.sdf, hull.grid)
    radii = np.linalg.norm(mesh.vertices, axis=1)
    # a hull circumscribes the sphere; with 24 views it is within a few % of it
    assert radii.min() > 0.5 - 0.02
    assert np.median(radii) < 0.5 * 1.06
    assert mesh.is_watertight and mesh.volume > 0


def test_empty_masks_are_an_input_error() -> None:
    dataset = _sphere_dataset(0.5, views=4)
    dataset.masks[2] = 0.0
    with pytest.raises(ReconstructionError, match="view2.png: the object mask is empty"):
        visual_hull(dataset, 16, torch.device("cpu"))


def test_neus_opacity_is_one_across_a_sharp_surface_and_zero_in_free_space() -> None:
    depth = torch.linspace(0, 1, 201)[None]
    sdf = 0.5 - depth                           # surface at t = 0.5, inside beyond
    weights = composite_weights(neus_alpha(sdf, torch.tensor(400.0)))
    assert abs(float(weights.sum()) - 1.0) < 1e-3
    peak = float(depth[0, :-1][weights[0].argmax()])
    assert abs(peak - 0.5) <= 0.01
    free = composite_weights(neus_alpha(0.3 + 0 * depth, torch.tensor(400.0)))
    assert float(free.sum()) < 1e-6


def test_marching_cubes_of_a_sphere_and_the_empty_error() -> None:
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 40)
    sdf = grid.node_positions().norm(dim=-1) - 0.7
    mesh = extract_mesh(sdf, grid)
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * 0.7 ** 3, rel=0.01)
    assert np.allclose(np.linalg.norm(mesh.vertices, axis=1), 0.7, atol=2e-3)
    with pytest.raises(ReconstructionError, match="level 0 found no surface.*--sdf-res"):
        extract_mesh(sdf + 2.0, grid, source="sdf.npz")


def test_small_components_are_dropped() -> None:
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 40)
    positions = grid.node_positions()
    big = positions.norm(dim=-1) - 0.6
    small = (positions - torch.tensor([0.85, 0.85, 0.85])).norm(dim=-1) - 0.08
    mesh = extract_mesh(torch.minimum(big, small), grid, min_component=0.05)
    assert len(mesh.split(only_watertight=False)) == 1
    assert np.linalg.norm(mesh.vertices, axis=1).max() < 0.62


def test_poisson_disk_set_is_maximal_and_respects_the_radius() -> None:
    rng = np.random.default_rng(0)
    points = rng.random((4000, 2))
    points = np.concatenate([points, np.zeros((4000, 1))], axis=1)
    kept = maximal_poisson_disk(points, 0.05, rng.random(4000))
    chosen = points[kept]
    from scipy.spatial import cKDTree
    distances, _ = cKDTree(chosen).query(chosen, k=2)
    assert distances[:, 1].min() >= 0.05
    # maximal: every candidate is within the radius of a kept point
    nearest, _ = cKDTree(chosen).query(points)
    assert nearest.max() < 0.05


def test_surface_particles_are_even_and_exactly_counted() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    rng = np.random.default_rng(1)
    points, normals, spacing = sample_surface_even(sphere, 3000, rng)
    assert points.shape == (3000, 3)
    assert np.allclose(np.linalg.norm(points, axis=1), 1.0, atol=2e-3)
    assert np.all(np.einsum("ij,ij->i", normals, points) > 0.99)
    assert spacing_variation(points) <= 0.2          # random sampling gives about 0.5
    random_points, _ = trimesh.sample.sample_surface(sphere, 3000, seed=1)
    assert spacing_variation(np.asarray(random_points)) > 0.4


def test_particles_rest_volume_sums_to_mesh_volume_and_nv0_gives_surface_only() -> None:
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 40)
    sdf = grid.node_positions().norm(dim=-1) - 0.7
    mesh = extract_mesh(sdf, grid)
    rng = np.random.default_rng(2)
    particles = sample_particles(mesh, sdf, grid, n_surface=1500, nv=4, particle_resolution=12,
                                 rng=rng)
    assert particles.num_surface == 1500
    interior = particles.position[~particles.is_surface]
    assert len(interior) > 0 and np.linalg.norm(interior, axis=1).max() < 0.7 + 1e-3
    assert particles.volume.sum() == pytest.approx(mesh.volume, rel=1e-9)
    assert np.all(particles.volume > 0)
    # interior samples are uniform: per-voxel volume shares are about voxel / nv
    deep = np.linalg.norm(particles.position, axis=1) < 0.4
    assert np.median(particles.volume[deep]) == pytest.approx(particles.interior_voxel ** 3 / 4,
                                                              rel=0.1)
    surface_only = sample_particles(mesh, sdf, grid, n_surface=800, nv=0, particle_resolution=12,
                                    rng=np.random.default_rng(3))
    assert surface_only.num_interior == 0 and surface_only.num_surface == 800
    assert surface_only.volume.sum() == pytest.approx(mesh.volume, rel=1e-9)


def test_a_shell_keeps_interior_particles_in_its_wall_and_the_walls_volume() -> None:
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 48)
    sdf = grid.node_positions().norm(dim=-1) - 0.7
    mesh = extract_mesh(sdf, grid)
    wall = 0.2
    hollow = sample_particles(mesh, sdf, grid, n_surface=1500, nv=4, particle_resolution=24,
                              rng=np.random.default_rng(2), shell=wall)
    radius = np.linalg.norm(hollow.position[~hollow.is_surface], axis=1)
    assert hollow.num_interior > 0 and radius.min() > 0.7 - wall - 1e-3 and radius.max() < 0.7 + 1e-3
    shell_volume = 4.0 / 3.0 * np.pi * (0.7 ** 3 - (0.7 - wall) ** 3)
    assert hollow.volume.sum() == pytest.approx(shell_volume, rel=0.05)
    solid = sample_particles(mesh, sdf, grid, n_surface=1500, nv=4, particle_resolution=24,
                             rng=np.random.default_rng(2))
    assert hollow.num_interior < 0.8 * solid.num_interior


def test_distribute_volume_gives_empty_voxels_to_the_nearest_particle() -> None:
    lattice = VoxelGrid((0.0, 0.0, 0.0), 1.0, (3, 1, 1))
    position = np.array([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    volume = distribute_volume(position, lattice, np.array([1.0, 2.0, 4.0]))
    assert np.allclose(volume, [0.5, 6.5])  # voxel 2 (no particle) goes to the nearest


def test_chamfer_distance_of_a_scaled_sphere() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    bigger = trimesh.creation.icosphere(subdivisions=5, radius=1.02)
    result = chamfer_distance(bigger, sphere, samples=20000)
    assert result["chamfer"] == pytest.approx(0.02, abs=0.002)
    assert result["diagonal"] == pytest.approx(2 * math.sqrt(3), rel=1e-3)


def _reference_ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """SSIM with a dense 11x11 window, zero 'same' padding (3DGS's formulation)."""
    offsets = torch.arange(11, dtype=torch.float64) - 5
    taps = torch.exp(-offsets ** 2 / (2 * 1.5 ** 2))
    window = (taps[:, None] * taps[None, :]) / taps.sum() ** 2
    window = window.expand(3, 1, 11, 11).to(x.dtype)
    a, b = x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None]

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, window, padding=5, groups=3)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    value = ((2 * mu_a * mu_b + 1e-4) * (2 * cov + 9e-4)) / (
        (mu_a ** 2 + mu_b ** 2 + 1e-4) * (var_a + var_b + 9e-4))
    return value.mean()


def test_ssim_and_psnr() -> None:
    generator = torch.Generator().manual_seed(0)
    x = torch.rand(40, 50, 3, generator=generator, dtype=torch.float64)
    y = (x + 0.05 * torch.randn(40, 50, 3, generator=generator, dtype=torch.float64)).clamp(0, 1)
    assert float(ssim(x, y)) == pytest.approx(float(_reference_ssim(x, y)), abs=1e-10)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-12)
    batch = ssim(torch.stack([x, y]), torch.stack([y, y]))
    assert batch.shape == (2,) and float(batch[1]) == pytest.approx(1.0)
    mse = float(((x - y) ** 2).mean())
    assert float(psnr(x, y)) == pytest.approx(-10 * math.log10(mse))
    z = x.clone().requires_grad_(True)
    (1 - ssim(z, y)).backward()
    assert z.grad is not None and torch.isfinite(z.grad).all()


def _pixel_rays(camera: Camera, size: int) -> tuple[np.ndarray, np.ndarray]:
    """World origin (3,) and directions (size, size, 3) of the rays through the pixel centres of a
    size x size ``camera``, scaled to camera depth 1 (a point at depth d is origin + d * direction)."""
    column, row = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    local = np.stack([(column - camera.cx) / camera.fx, (row - camera.cy) / camera.fy,
                      np.ones_like(column)], -1)
    camera_to_world = np.linalg.inv(camera.world_to_camera.double().numpy())
    return camera_to_world[:3, 3], local @ camera_to_world[:3, :3].T


def _pit_depth_map(view: int, eye: np.ndarray, size: int, inside) -> "DepthMap":
    """Depth map (camera z) of the first point along each pixel's ray where ``inside`` holds,
    found by marching (what a perfect stereo matcher would measure)."""
    from fracture_gs.recon.carving import DepthMap
    camera = Camera.look_at(eye, (0, 0, 0), (0, 1, 0), fov_x_rad=0.9, width=size, height=size)
    origin, direction = _pixel_rays(camera, size)
    steps = np.linspace(2.0, 4.0, 401)           # the cube lies between depths 2.4 and 3.6
    points = steps[None, :, None] * direction.reshape(-1, 1, 3) + origin
    hit = inside(points)
    first = np.where(hit.any(axis=1), steps[hit.argmax(axis=1)], np.nan)
    return DepthMap(view, camera, first.reshape(size, size).astype(np.float32))


def test_carving_removes_the_free_space_that_depth_maps_see_and_nothing_else() -> None:
    """The hull is a full cube; the object has a cylindrical pit in its top that cameras
    above see into. Carving must open the pit and keep the solid."""
    from fracture_gs.recon.carving import CarveSettings, carve_with_depth
    grid = VoxelGrid((-1.0, -1.0, -1.0), 2.0 / 32, (33, 33, 33))
    nodes = grid.node_positions(dtype=torch.float64).numpy()
    half = 0.6
    cube = np.max(np.abs(nodes) - half, axis=-1)                     # hull: cube SDF (inside)
    hull = torch.from_numpy(cube).float()

    def inside(points: np.ndarray) -> np.ndarray:
        in_cube = np.all(np.abs(points) < half, axis=-1)
        in_pit = (np.hypot(points[..., 0], points[..., 1]) < 0.3) & (points[..., 2] > 0.2)
        return in_cube & ~in_pit

    eyes = [np.array([0.4 * math.cos(a), 0.4 * math.sin(a), 3.0])
            for a in np.linspace(0, 2 * math.pi, 6, endpoint=False)]
    maps = [_pit_depth_map(v, eye, 48, inside) for v, eye in enumerate(eyes)]
    carved, count = carve_with_depth(hull, grid, maps, CarveSettings(votes=2, margin_voxels=2.0))
    assert count > 0

    def value(point: tuple[float, float, float]) -> float:
        return float(sample_dense(carved.double(), grid,
                                  torch.tensor([point], dtype=torch.float64))[0])

    assert value((0.0, 0.0, 0.45)) > 0          # the pit is open
    assert value((0.05, -0.05, 0.35)) > 0
    assert value((0.0, 0.0, -0.2)) < 0          # below the pit bottom: solid
    assert value((0.45, 0.45, 0.45)) < 0        # beside the pit: solid
    assert value((0.0, 0.0, -0.45)) < 0
    # nothing outside the pit's cylinder (plus a few voxels of smoothing) changed sign
    radius = np.hypot(nodes[..., 0], nodes[..., 1])
    flipped = (carved.numpy() > 0) & (cube < 0)
    assert flipped.any() and np.all(radius[flipped] < 0.3 + 3 * grid.voxel)
    assert np.all(nodes[..., 2][flipped] > 0.2 - 3 * grid.voxel)


def _plane_depth_map(view: int, eye: np.ndarray, size: int, plane_z: float) -> "DepthMap":
    """Depth map (camera z) of the plane z = ``plane_z`` seen from ``eye`` (looking at the origin)."""
    from fracture_gs.recon.carving import DepthMap
    camera = Camera.look_at(eye, (0, 0, 0), (0, 1, 0), fov_x_rad=0.6, width=size, height=size)
    origin, direction = _pixel_rays(camera, size)
    depth = (plane_z - origin[2]) / direction[..., 2]
    return DepthMap(view, camera, depth.astype(np.float32))


def test_depth_fusion_keeps_confirmed_and_single_depths_and_drops_seen_through_ones() -> None:
    """A depth two nearby maps agree with is confirmed; one that only one agrees with is kept as
    'single' unless another map sees a surface behind it (its ray passes through the point)."""
    from fracture_gs.recon.carving import CarveSettings, DepthMap, consistent_depths
    eyes = [np.array([x, 0.0, 3.0]) for x in (0.0, 0.3, -0.3, 0.6)]
    directions = np.stack([eye / np.linalg.norm(eye) for eye in eyes])
    truth = [_plane_depth_map(v, eye, 32, 0.0) for v, eye in enumerate(eyes)]
    behind = _plane_depth_map(2, eyes[2], 32, -0.5)        # map 2 sees a surface 0.5 lower
    blank = DepthMap(2, truth[2].camera, np.full_like(truth[2].depth, np.nan))
    blank3 = DepthMap(3, truth[3].camera, np.full_like(truth[3].depth, np.nan))
    settings = CarveSettings(neighbours=3, consistent_views=2)
    voxel = 0.02

    def kinds(maps: list) -> tuple[float, float]:
        confirmed, single = consistent_depths(maps, directions, voxel, settings)
        return (float(np.isfinite(confirmed[0].depth).mean()),
                float(np.isfinite(single[0].depth).mean()))

    assert kinds(truth) == (1.0, 0.0)                            # 3 maps agree with map 0
    assert kinds([truth[0], truth[1], blank, blank3]) == (0.0, 1.0)   # only map 1 does
    assert kinds([truth[0], truth[1], behind, blank3]) == (0.0, 0.0)  # map 2 sees through it


def test_single_confirmed_depths_carve_where_enough_of_them_agree() -> None:
    """The pit of the carving test, seen only by single-confirmed depths: carved when at least
    ``single_view_votes`` of them see a node as free space, untouched when fewer can."""
    from fracture_gs.recon.carving import CarveSettings, carve_with_depth
    grid = VoxelGrid((-1.0, -1.0, -1.0), 2.0 / 32, (33, 33, 33))
    nodes = grid.node_positions(dtype=torch.float64).numpy()
    hull = torch.from_numpy(np.max(np.abs(nodes) - 0.6, axis=-1)).float()

    def inside(points: np.ndarray) -> np.ndarray:
        in_pit = (np.hypot(points[..., 0], points[..., 1]) < 0.3) & (points[..., 2] > 0.2)
        return np.all(np.abs(points) < 0.6, axis=-1) & ~in_pit

    eyes = [np.array([0.4 * math.cos(a), 0.4 * math.sin(a), 3.0])
            for a in np.linspace(0, 2 * math.pi, 6, endpoint=False)]
    maps = [_pit_depth_map(v, eye, 48, inside) for v, eye in enumerate(eyes)]
    carved, count = carve_with_depth(hull, grid, [], CarveSettings(single_view_votes=3,
                                                                   margin_voxels=2.0), maps)
    assert count > 0
    assert float(sample_dense(carved.double(), grid,
                              torch.tensor([[0.0, 0.0, 0.45]], dtype=torch.float64))[0]) > 0
    _, none = carve_with_depth(hull, grid, [], CarveSettings(single_view_votes=7), maps)
    assert none == 0                                             # only 6 maps: never 7 votes


def test_carve_settings_reject_bad_scales() -> None:
    from fracture_gs.recon.carving import CarveSettings
    with pytest.raises(ValueError, match="window odd"):
        CarveSettings(scales=((2, 8),))
    with pytest.raises(ValueError, match="at least one"):
        CarveSettings(scales=())


def _textured_plane_view(eye: np.ndarray, size: int, depth_z: float, half: float
                         ) -> tuple[Camera, np.ndarray, np.ndarray]:
    """A camera at ``eye`` looking down -z at the square |x|, |y| < half of the plane z = depth_z,
    which carries a fixed random texture: its grey image and the square's mask."""
    camera = Camera.look_at(eye, (0, 0, depth_z), (0, 1, 0), fov_x_rad=0.6, width=size, height=size)
    origin, direction = _pixel_rays(camera, size)
    hit = origin + direction * ((depth_z - origin[2]) / direction[..., 2])[..., None]
    texture = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    cell = np.clip(((hit[..., :2] + 1.0) * 32).astype(int), 0, 63)
    mask = np.all(np.abs(hit[..., :2]) < half, axis=-1)
    return camera, np.where(mask, texture[cell[..., 1], cell[..., 0]], 0.0).astype(np.float32), mask


def test_stereo_depth_only_from_windows_wholly_on_the_object() -> None:
    """The plane sweep finds the depth of a textured square, but gives none where its NCC window
    reaches past the square's outline: there the window also compares background, and on a part
    seen edge-on such a depth lies behind the part and would carve it."""
    from fracture_gs.recon.carving import sweep_depth
    window = 7
    views = [_textured_plane_view(np.array([dx, dy, 3.0]), 64, 0.0, 0.5)
             for dx, dy in ((0.0, 0.0), (0.4, 0.0), (-0.4, 0.0), (0.0, 0.4))]
    cameras = [view[0] for view in views]
    gray = np.stack([view[1] for view in views])
    mask = views[0][2]
    planes = np.linspace(2.5, 3.5, 41)
    depth = sweep_depth(0, [1, 2, 3], gray, cameras, mask, planes, window, 0.8)
    distance_to_outline = ndimage.distance_transform_cdt(mask, metric="chessboard")
    deep = distance_to_outline > window // 2
    rim = mask & ~deep
    assert np.isfinite(depth[deep]).mean() > 0.75
    assert np.nanpercentile(np.abs(depth[deep] - 3.0), 95) <= 2 * (planes[1] - planes[0])
    assert rim.any() and not np.isfinite(depth[rim]).any()
    assert not np.isfinite(depth[~mask]).any()
