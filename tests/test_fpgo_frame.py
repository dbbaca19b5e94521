"""The Gaussians of a frame: binding to a model, scene transform, following F_E, and FPGO."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.gaussians import read_ply
from fracture_gs.mpm.scene import rotation_matrix_xyz
from fracture_gs.render import Camera, rasterize
from fracture_gs.render.frame_gaussians import ModelError, SceneGaussians, read_frame_ply
from fracture_gs.folders.sim_reader import SimFrame, Simulation
from render_scenes import (SPACING, block_scene, identity_frames, lattice_block, write_model,
                           write_sim)

TRANSFORM = {"scale": 1.5, "rotate_deg": [20.0, -35.0, 50.0], "translate": [0.5, 0.45, 0.55]}


def transformed(points: np.ndarray) -> np.ndarray:
    rotation = rotation_matrix_xyz(tuple(TRANSFORM["rotate_deg"]))
    return TRANSFORM["translate"] + TRANSFORM["scale"] * points @ rotation.T


def particle_arrays(points_world: np.ndarray, surface: np.ndarray) -> dict[str, np.ndarray]:
    count = points_world.shape[0]
    gaussian_index = np.full(count, -1, dtype=np.int64)
    gaussian_index[np.nonzero(surface)[0]] = np.arange(int(surface.sum()))
    return {"rest_x": points_world.astype(np.float32), "obj_id": np.zeros(count, np.int32),
            "is_surface": surface, "gaussian_index": gaussian_index,
            "rest_volume": np.full(count, (TRANSFORM["scale"] * SPACING) ** 3, np.float32)}


def make_block(folder: Path, jitter: float = 0.0):
    """A trained-looking block (SH degree 2) placed by TRANSFORM; frame 0 at rest. ``jitter``
    (in spacings) moves the lattice points at random, so that distances have no ties."""
    points, surface = lattice_block((0.06, 0.04, 0.04))
    points = points + jitter * SPACING * np.random.default_rng(3).uniform(-1, 1, points.shape)
    tmp_path = folder
    model = write_model(tmp_path / "model", points, surface, sh_degree=2)
    rest = transformed(points)
    root = write_sim(tmp_path / "sim", block_scene(tmp_path / "model", TRANSFORM),
                     particle_arrays(rest, surface), identity_frames(rest, 1))
    return Simulation.open(root), model, points, surface


@pytest.fixture()
def block(tmp_path: Path):
    return make_block(tmp_path)


def orbit_camera(angle: float, size: int = 48) -> Camera:
    eye = [0.5 + 0.45 * math.cos(angle), 0.45 + 0.45 * math.sin(angle), 0.75]
    return Camera.look_at(eye, [0.5, 0.45, 0.55], [0, 0, 1], math.radians(45), size, size)


def test_frame_zero_is_the_model_seen_through_the_scene_transform(block):
    sim, model, _, _ = block
    scene = SceneGaussians.from_simulation(sim)
    gaussians = scene.frame(sim.load_frame(0), fpgo=True)
    assert len(gaussians) == model.num_gaussians and not (gaussians.exclusive >= 0).any()
    rotation = rotation_matrix_xyz(tuple(TRANSFORM["rotate_deg"]))
    background = torch.tensor([1.0, 1.0, 1.0])
    for angle in (0.3, 2.2, 4.0):
        world_camera = orbit_camera(angle)
        image = gaussians.rasterize(world_camera, background)["rgb"]
        # the same picture: the model in its own frame, the camera moved by the inverse transform
        w2c = world_camera.world_to_camera.double()
        T = torch.eye(4, dtype=torch.float64)
        T[:3, :3] = TRANSFORM["scale"] * torch.as_tensor(rotation)
        T[:3, 3] = torch.tensor(TRANSFORM["translate"])
        model_w2c = w2c @ T
        model_w2c[:3, :] /= TRANSFORM["scale"]  # undo the scale of camera space (same pixels)
        model_camera = Camera(model_w2c.float(), world_camera.fx, world_camera.fy, world_camera.cx,
                              world_camera.cy, world_camera.width, world_camera.height)
        with torch.no_grad():
            expected = rasterize(model.means, model.opacities, model_camera, scales=model.scales,
                                 quats=model.rotations, sh=model.sh, background=background)["rgb"]
        assert (image - expected).abs().max().item() < 2e-4
        assert (image < 0.9).any()  # the block is in view


def test_gaussians_follow_a_rigid_rotation_with_their_colours(block):
    sim, _, _, _ = block
    scene = SceneGaussians.from_simulation(sim)
    rest = sim.load_frame(0)
    angle = 0.8
    Q = torch.tensor(rotation_matrix_xyz((30.0, 10.0, math.degrees(angle))), dtype=torch.float32)
    centre = torch.tensor([0.5, 0.45, 0.55])
    moved = SimFrame(1, centre + (rest.x - centre) @ Q.T, Q.expand_as(rest.F_E).contiguous(),
                     rest.fractured)
    camera = orbit_camera(1.0)
    image = scene.frame(moved, fpgo=False).rasterize(camera)["rgb"]
    # the camera that sees the rotated object as `camera` sees it at rest
    T = torch.eye(4)
    T[:3, :3] = Q
    T[:3, 3] = centre - Q @ centre
    at_rest = Camera(camera.world_to_camera @ T, camera.fx, camera.fy, camera.cx, camera.cy,
                     camera.width, camera.height)
    expected = scene.frame(rest, fpgo=False).rasterize(at_rest)["rgb"]
    assert (image - expected).abs().max().item() < 2e-4


def crack_frame(sim: Simulation, points: np.ndarray, gap: float) -> SimFrame:
    """The right half (x > 0 in the model frame) moved by `gap` along the model x axis; the
    particles within 1.5 spacings of the cut are fractured."""
    rest = sim.load_frame(0)
    axis = torch.tensor(rotation_matrix_xyz(tuple(TRANSFORM["rotate_deg"]))[:, 0],
                        dtype=torch.float32)
    right = torch.from_numpy(points[:, 0] > 1e-6)
    x = rest.x + gap * right[:, None].float() * axis
    fractured = torch.from_numpy(np.abs(points[:, 0]) < 1.5 * SPACING)
    return SimFrame(1, x, rest.F_E, fractured)


def test_fpgo_replaces_fractured_gaussians_by_exclusive_lenses(block):
    sim, _, points, surface = block
    scene = SceneGaussians.from_simulation(sim)
    frame = crack_frame(sim, points, gap=0.6 * SPACING)
    base = scene.frame(frame, fpgo=False)
    fpgo = scene.frame(frame, fpgo=True)
    stats = fpgo.stats
    assert stats.fractured == int(frame.fractured.sum()) > 0
    lenses = fpgo.exclusive >= 0
    assert int(lenses.sum()) == stats.lens_gaussians > 0
    # each lens is in the exclusive group of the fractured particle whose Gaussian it replaces
    assert torch.equal(fpgo.exclusive[lenses], fpgo.particle[lenses])
    assert fpgo.exclusive_rule == "group" and torch.equal(fpgo.exclusive_argument(), fpgo.exclusive)
    assert torch.equal(fpgo.is_fpgo, lenses | (fpgo.is_fpgo & ~lenses))
    # every lens follows a fractured particle and sits between it and an intact neighbour
    owners = fpgo.particle[lenses]
    assert frame.fractured[owners].all()
    d_c = 1.5 * TRANSFORM["scale"] * SPACING
    x = frame.x
    intact = x[~frame.fractured]
    for centre, owner in zip(fpgo.means[lenses], owners):
        near = intact[(intact - x[owner]).norm(dim=1) <= d_c * (1 + 1e-6)]
        segment = near - x[owner]
        t = ((centre - x[owner]) * segment).sum(1) / (segment * segment).sum(1)
        off_segment = (x[owner] + t[:, None] * segment - centre).norm(dim=1)
        best = int(off_segment.argmin())
        assert off_segment[best] < 1e-5 and 0.0 < t[best] < 1.0
    # replaced particles keep no original Gaussian; the others keep theirs
    replaced = torch.unique(owners)
    kept_original = fpgo.particle[~fpgo.is_fpgo]
    assert not torch.isin(kept_original, replaced).any()
    expected_kept = base.particle[~torch.isin(base.particle, replaced)]
    assert torch.equal(torch.sort(kept_original).values, torch.sort(expected_kept).values)
    # a lens inherits opacity, SH and view rotation of its particle's own Gaussian
    own_rows = {int(p): i for i, p in enumerate(base.particle)}
    for row in torch.nonzero(lenses).flatten()[:20]:
        own = own_rows.get(int(fpgo.particle[row]))
        if own is not None:
            assert torch.equal(fpgo.sh[row], base.sh[own])
            assert fpgo.opacities[row] == base.opacities[own]


def test_lens_exclusive_rules_and_their_ply_round_trip(block, tmp_path: Path):
    """'group' (the default, paper §3.2.2) lies between 'none' (lenses blend like all others)
    and 'all' (the global rule of docs/formulas.md §11, the fewest lenses per pixel) in how much the lenses
    cover; each rule survives write_ply / read_frame_ply."""
    sim, _, points, _ = block
    frame = crack_frame(sim, points, gap=0.6 * SPACING)
    camera = orbit_camera(0.3, 64)
    alpha = {}
    for rule in ("group", "all", "none"):
        gaussians = SceneGaussians.from_simulation(sim, settings=FPGOSettings(exclusive=rule)).frame(frame)
        lenses = gaussians.exclusive >= 0
        assert bool(lenses.any()) == (rule != "none")
        alpha[rule] = gaussians.rasterize(camera)["alpha"]
        path = tmp_path / f"{rule}.ply"
        gaussians.write_ply(path)
        model, exclusive = read_frame_ply(path)
        assert torch.equal(exclusive, lenses if rule == "all" else gaussians.exclusive)
    # fewer blended lenses, less coverage, up to the early stop (T < 1e-4 ends a pixel before
    # the entry that would cross it, so a pixel may keep T up to 1e-4 / (1 - 0.99))
    assert torch.all(alpha["all"] <= alpha["group"] + 1e-2)
    assert torch.all(alpha["group"] <= alpha["none"] + 1e-2)
    assert (alpha["none"] - alpha["group"]).max() > 1e-3 and (alpha["group"] - alpha["all"]).max() > 1e-3
    assert FPGOSettings(exclusive=False).exclusive == "none"  # the earlier bool setting
    with pytest.raises(ValueError, match="exclusive"):
        FPGOSettings(exclusive="some")


def test_fractured_interior_particles_get_interpolated_gaussians(tmp_path: Path):
    sim, model, points, surface = make_block(tmp_path, jitter=0.15)
    scene = SceneGaussians.from_simulation(sim, settings=FPGOSettings(k_neighbours=1))
    frame = crack_frame(sim, points, gap=3.0 * SPACING)  # too wide to find partners across
    fpgo = scene.frame(frame, fpgo=True)
    interior = fpgo.is_fpgo & (fpgo.exclusive < 0)
    owners = fpgo.particle[interior]
    assert interior.any() and not torch.from_numpy(surface)[owners].any()
    # appearance: inverse-distance mean of the 4 nearest surface Gaussians at rest
    rest = sim.particles.rest_x.astype(np.float64)
    centres = rest[surface]
    sh = model.sh.detach().numpy()
    opacity = model.opacities.detach().numpy()
    checked = 0
    for row, owner in zip(torch.nonzero(interior).flatten(), owners):
        distance = np.linalg.norm(centres - rest[int(owner)], axis=1)
        order = np.argsort(distance, kind="stable")
        if distance[order[4]] - distance[order[3]] < 1e-5:  # a tie: any 4 of them fit
            continue
        checked += 1
        nearest = order[:4]
        weight = 1.0 / distance[nearest]
        weight /= weight.sum()
        assert fpgo.opacities[row].item() == pytest.approx(float(weight @ opacity[nearest]), rel=1e-5)
        assert np.allclose(fpgo.sh[row].numpy(), np.einsum("k,kcd->cd", weight, sh[nearest]),
                           atol=1e-5)
        # isotropic, scale = spacing / 2 (F_E = I here), centred on the particle
        scale = 0.5 * TRANSFORM["scale"] * SPACING
        assert torch.allclose(fpgo.covariances[row], scale ** 2 * torch.eye(3), rtol=1e-4)
        assert torch.allclose(fpgo.means[row], frame.x[owner])
    assert checked >= 5


def test_an_interior_colour_paints_the_faces_a_fracture_opens(tmp_path: Path):
    points, surface = lattice_block((0.06, 0.04, 0.04))
    points = points + 0.15 * SPACING * np.random.default_rng(3).uniform(-1, 1, points.shape)
    write_model(tmp_path / "model", points, surface, sh_degree=2)
    scene = block_scene(tmp_path / "model", TRANSFORM)
    scene["objects"][0]["materials"][0]["interior_colour"] = [0.95, 0.9, 0.8]
    rest = transformed(points)
    sim = Simulation.open(write_sim(tmp_path / "sim", scene, particle_arrays(rest, surface),
                                    identity_frames(rest, 1)))
    assert sim.scene.objects[0].materials[0].interior_colour == (0.95, 0.9, 0.8)
    fpgo = SceneGaussians.from_simulation(sim, settings=FPGOSettings(k_neighbours=1)).frame(
        crack_frame(sim, points, gap=3.0 * SPACING), fpgo=True)
    interior = fpgo.is_fpgo & (fpgo.exclusive < 0)
    assert interior.any()
    colour = 0.5 + 0.28209479177387814 * fpgo.sh[interior][:, 0]      # SH degree 0 seen from anywhere
    assert torch.allclose(colour, torch.tensor([0.95, 0.9, 0.8]).expand_as(colour), atol=1e-5)
    assert not fpgo.sh[interior][:, 1:].any()
    # the surface keeps its trained colours
    assert not torch.allclose(fpgo.sh[~fpgo.is_fpgo][:, 0], fpgo.sh[interior][:1, 0].expand(int((~fpgo.is_fpgo).sum()), 3))


@pytest.mark.parametrize("colour, message", [([1.2, 0, 0], "each channel must be in [0, 1]"),
                                             ([0.5, 0.5], "expected a list of 3 numbers")])
def test_a_bad_interior_colour_names_its_key(colour: list, message: str):
    from fracture_gs.config.scene import SceneError, parse_scene

    scene = block_scene(None)
    scene["objects"][0]["materials"][0]["interior_colour"] = colour
    with pytest.raises(SceneError, match=r"objects\[0\]\.materials\[0\]\.interior_colour") as error:
        parse_scene(scene)
    assert message in str(error.value)


def test_only_exposed_fractured_interior_particles_are_drawn(tmp_path: Path):
    """The NACC flag marks a damaged volume; FPGO's default draws its interior particles only on
    a fracture surface (they kept fewer than ``exposure`` of their rest neighbours), the buried
    ones stay undrawn as without fracture; ``interior="all"`` draws every one (``--interior all``;
    as written)."""
    sim, _, points, surface = make_block(tmp_path, jitter=0.15)
    frame = crack_frame(sim, points, gap=3.0 * SPACING)
    band = torch.from_numpy(np.abs(points[:, 0]) < 3.5 * SPACING)   # a thick damaged band
    frame = SimFrame(frame.index, frame.x, frame.F_E, band)
    interior = torch.from_numpy(~surface)
    drawn = {}
    for rule in ("exposed", "all"):
        gaussians = SceneGaussians.from_simulation(sim, settings=FPGOSettings(interior=rule)).frame(frame)
        owners = torch.unique(gaussians.particle[gaussians.is_fpgo])
        drawn[rule] = owners[interior[owners]]                 # interior particles FPGO draws
        buried = gaussians.stats.buried_particles
        assert (buried > 0) == (rule == "exposed")
    # the share of each particle's rest neighbours (within d_c) that the cut moved to the other
    # side: a particle on a face of the cut loses them, one away from it keeps all of them
    right = torch.from_numpy(points[:, 0] > 1e-6)
    rest = sim.load_frame(0).x
    d_c = 1.5 * TRANSFORM["scale"] * SPACING
    near = (rest[:, None] - rest[None]).norm(dim=2) <= d_c
    near.fill_diagonal_(False)
    across = (near & (right[:, None] != right[None])).sum(1) / near.sum(1).clamp_min(1)
    drawn_mask = torch.zeros_like(band)
    drawn_mask[drawn["exposed"]] = True
    candidates = band & interior
    assert drawn_mask[candidates & (across >= 0.25)].all()          # on a face: drawn
    assert not drawn_mask[candidates & (across == 0)].any()         # buried: not drawn
    assert (candidates & (across >= 0.25)).any() and (candidates & (across == 0)).any()
    # "all": every fractured interior particle has an FPGO Gaussian (its own or lenses)
    assert torch.equal(torch.sort(drawn["all"]).values, torch.nonzero(band & interior).flatten())
    stats = SceneGaussians.from_simulation(sim).frame(frame).stats
    assert stats.buried_particles == int((band & interior).sum()) - drawn["exposed"].numel()
    with pytest.raises(ValueError, match="interior"):
        FPGOSettings(interior="some")
    with pytest.raises(ValueError, match="exposure"):
        FPGOSettings(exposure=0.0)


def test_small_fragments_are_not_drawn_with_fpgo(block):
    sim, _, points, _ = block
    scene = SceneGaussians.from_simulation(sim, settings=FPGOSettings(min_fragment=10))
    rest = sim.load_frame(0)
    corner = torch.from_numpy((points[:, 0] > 0.05) & (points[:, 1] > 0.03) & (points[:, 2] > 0.03))
    assert 0 < int(corner.sum()) < 10
    x = rest.x.clone()
    x[corner] += torch.tensor([0.2, 0.0, 0.0])     # a crumb flies off
    frame = SimFrame(1, x, rest.F_E, corner.clone())
    fpgo = scene.frame(frame, fpgo=True)
    base = scene.frame(frame, fpgo=False)
    assert fpgo.stats.hidden_particles == int(corner.sum())
    assert not torch.isin(fpgo.particle, torch.nonzero(corner).flatten()).any()
    assert torch.isin(base.particle, torch.nonzero(corner).flatten()).any()


def test_without_fracture_fpgo_draws_the_baseline(block):
    sim, _, _, _ = block
    scene = SceneGaussians.from_simulation(sim)
    frame = sim.load_frame(0)
    with_fpgo, without = scene.frame(frame, fpgo=True), scene.frame(frame, fpgo=False)
    for name in ("means", "covariances", "opacities", "sh", "view_rotations", "particle"):
        assert torch.equal(getattr(with_fpgo, name), getattr(without, name))


def test_primitive_objects_draw_flat_coloured_surface_particles(tmp_path: Path):
    points, surface = lattice_block((0.05, 0.05, 0.05))
    rest = points + 0.5
    count = points.shape[0]
    arrays = {"rest_x": rest.astype(np.float32), "obj_id": np.zeros(count, np.int32),
              "is_surface": surface, "gaussian_index": np.full(count, -1),
              "rest_volume": np.full(count, SPACING ** 3, np.float32)}
    sim = Simulation.open(write_sim(tmp_path / "sim", block_scene(None), arrays,
                                    identity_frames(rest, 1)))
    scene = SceneGaussians.from_simulation(sim)
    gaussians = scene.frame(sim.load_frame(0))
    assert len(gaussians) == int(surface.sum())
    assert scene.sources == ["flat colour"]
    assert gaussians.sh.shape[1] == 1 and torch.unique(gaussians.sh, dim=0).shape[0] == 1
    scale = 0.5 * SPACING  # spacing from the rest volume
    assert torch.allclose(gaussians.covariances, scale ** 2 * torch.eye(3).expand_as(gaussians.covariances),
                          rtol=1e-4)


def test_model_errors_name_the_folder(block, tmp_path: Path):
    sim, _, _, _ = block
    ply = next((sim.scene.objects[0].model / "point_cloud").rglob("point_cloud.ply"))
    ply.unlink()
    with pytest.raises(ModelError, match="no point_cloud/iteration_"):
        SceneGaussians.from_simulation(sim)


def test_binding_draws_each_referenced_gaussian_once_with_its_rest_offset(tmp_path: Path):
    # two particles per Gaussian (as with train.py --from-ply): the nearer one drives it
    points, surface = lattice_block((0.04, 0.04, 0.04))
    model = write_model(tmp_path / "model", points, surface)
    surface_rows = np.nonzero(surface)[0]
    rest = transformed(points)
    arrays = particle_arrays(rest, surface)
    shifted = rest.copy()
    shifted[surface_rows] += 0.3 * SPACING          # the particles sit beside their Gaussians
    doubled = {"rest_x": np.concatenate([shifted, rest[surface_rows] + 0.9 * SPACING]).astype(np.float32),
               "obj_id": np.zeros(len(rest) + len(surface_rows), np.int32),
               "is_surface": np.concatenate([surface, np.ones(len(surface_rows), bool)]),
               "gaussian_index": np.concatenate([arrays["gaussian_index"], np.arange(len(surface_rows))]),
               "rest_volume": np.concatenate([arrays["rest_volume"], arrays["rest_volume"][surface_rows]])}
    sim = Simulation.open(write_sim(tmp_path / "sim", block_scene(tmp_path / "model", TRANSFORM),
                                    doubled, identity_frames(doubled["rest_x"], 1)))
    gaussians = SceneGaussians.from_simulation(sim).frame(sim.load_frame(0))
    assert len(gaussians) == model.num_gaussians
    assert (gaussians.particle < len(rest)).all()       # the nearer particle drives
    expected = transformed(model.means.detach().double().numpy())
    assert np.allclose(gaussians.means.numpy(), expected, atol=1e-5)   # rest offset kept
    assert read_ply(str(next((tmp_path / "model").rglob("point_cloud.ply")))).num_gaussians == \
        model.num_gaussians


def test_spacing_from_train_py_particles_json_is_the_sparser_set(tmp_path: Path):
    # train.py writes surface_spacing + interior_particle_size: d_c must connect the sparser set
    import json

    from fracture_gs.folders.model_folder import model_spacing

    path = tmp_path / "particles.json"
    path.write_text(json.dumps({"surface_spacing": 0.0075, "interior_particle_size": 0.02,
                                "n_interior": 83747}))
    assert model_spacing(tmp_path) == pytest.approx(0.02)
    path.write_text(json.dumps({"surface_spacing": 0.0075, "interior_particle_size": 0.02,
                                "n_interior": 0}))          # surface only (--nv 0)
    assert model_spacing(tmp_path) == pytest.approx(0.0075)
    path.write_text(json.dumps({"spacing": 0.01, "surface_spacing": 0.5}))
    assert model_spacing(tmp_path) == pytest.approx(0.01)
    path.write_text(json.dumps({"interior_particle_size": 0.02}))
    with pytest.raises(ModelError, match="particles.json: no valid"):
        model_spacing(tmp_path)
