"""The compiled kernels on the worst cases of their input sizes, and their bounds.

Worst cases: hundreds of particles in one grid cell (all with the same stencil), every particle in
one 4x4x4 block, one piece holding every point (spatial kernels), every Gaussian on one tile
(rasterizer). Each kernel runs on them and agrees with its PyTorch twin. A violated bound (bins that
do not match the positions, an index outside its list, a key outside the grids) is one
``KernelBoundError`` line, and ``simulate.py`` reports it as one ``error:`` line with exit status 1
(docs/design_mpm.md, Memory safety).
"""
from __future__ import annotations

import dataclasses

import pytest
import torch

from fracture_gs._backend import KernelBoundError
from fracture_gs.fracture import ops as fracture_ops
from fracture_gs.fracture import spatial
from fracture_gs.materials import MaterialTable, NACCMaterial
from fracture_gs.mpm import ops, reference
from fracture_gs.mpm.grid import FragmentFields, GridFields, GridGeometry, ParticleBins
from fracture_gs.mpm.types import Domain
from fracture_gs.render import rasterize, rasterize_reference
from kernel_devices import KERNEL_DEVICES
from raster_scenes import make_camera, split

pytestmark = pytest.mark.extension  # tests/conftest.py: skipped without _C, failed in CI

REL_TOL = 1e-4
CPU = torch.device("cpu")


def rel_err(actual: torch.Tensor, expected: torch.Tensor) -> float:
    actual, expected = actual.detach().double().cpu(), expected.detach().double()
    scale = max(float(expected.abs().max()), 1e-30)
    return float((actual - expected).abs().max()) / scale


def crowded_particles(case: str, seed: int = 0) -> tuple[GridGeometry, dict[str, torch.Tensor]]:
    """Particles of two object grids on a 16-cell grid. ``one_cell``: 600 particles in one cell,
    placed so that they all share one stencil (its first node is the same for all); ``one_block``:
    2000 particles whose stencils all start in one 4x4x4-node block. Half of them belong to each
    grid (contact everywhere); a slab across the middle along x is damaged (fragments: particles
    on its two sides have opposite damage gradients)."""
    gen = torch.Generator().manual_seed(seed)
    geometry = GridGeometry.from_domain(Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 16), 2)
    dx = geometry.dx
    if case == "one_cell":  # x / dx in [8.5, 9.5): stencil base node 8 along every axis
        n, low, width = 600, 8.5 * dx, dx
    else:  # x / dx in [4.5, 8.5): stencil base nodes 4..7, block 1 along every axis
        n, low, width = 2000, 4.5 * dx, 4 * dx
    x = (low + width * torch.rand(n, 3, generator=gen)).contiguous()
    particles = {
        "x": x, "v": torch.randn(n, 3, generator=gen), "C": 3.0 * torch.randn(n, 3, 3, generator=gen),
        "stress": 1e3 * torch.randn(n, 3, 3, generator=gen), "mass": 0.5 + torch.rand(n, generator=gen),
        "rest_volume": 1e-5 * (0.5 + torch.rand(n, generator=gen)),
        "grid_id": (torch.arange(n) % 2).to(torch.int32),
        "damaged": (x[:, 0] - (low + 0.5 * width)).abs() < width / 6,
    }
    return geometry, particles


P2G_KEYS = ("x", "v", "C", "stress", "mass", "rest_volume")


def both_fields(geometry: GridGeometry) -> GridGeometry:
    return dataclasses.replace(geometry, n_grids=2 * geometry.n_grids)


def on(bins: ParticleBins, device: str) -> ParticleBins:
    return ParticleBins(*(getattr(bins, f.name).to(device) for f in dataclasses.fields(ParticleBins)))


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("width, grid", [(1.0, 50), (1.2, 48), (1.0, 48)])
def test_particles_at_block_boundaries_get_one_stencil_base(width, grid, device):
    """Particles within a few hundred roundings of every block boundary plane: the compiled and
    the torch binning agree, and P2G (whose window holds the block the binning chose) finds each
    particle's stencil in its block. On 50 cells over 1 m and 48 over 1.2 m an FMA-contracted
    base used to differ from the binning's there, and P2G wrote before its window."""
    import numpy as np

    geometry = GridGeometry.from_domain(Domain((0.0,) * 3, (width,) * 3, grid), 1)
    planes = []
    for m in range(1, grid // 4 - 1):
        plane = np.float32((4 * m + 0.5) * geometry.dx)
        planes.append(plane + np.arange(-300, 301, dtype=np.float32) * np.spacing(plane))
    along = torch.from_numpy(np.concatenate(planes).astype(np.float32))
    n = len(along)
    x = torch.full((n, 3), width / 2)
    x[torch.arange(n), torch.arange(n) % 3] = along  # each axis in turn
    x = x.contiguous()
    grid_id = torch.zeros(n, dtype=torch.int32)
    bins = ops.bin_particles(x, grid_id, geometry, backend="cpp")
    twin = reference.bin_particles(x, grid_id, geometry)
    for field in dataclasses.fields(ParticleBins):
        assert torch.equal(getattr(bins, field.name), getattr(twin, field.name)), field.name
    fields = GridFields.zeros(geometry, torch.device(device), with_contact=False)
    d = {"x": x, "v": torch.zeros(n, 3), "C": torch.zeros(n, 3, 3), "stress": torch.zeros(n, 3, 3),
         "mass": torch.ones(n), "rest_volume": torch.ones(n)}
    ops.p2g(on(bins if device == "cpu" else twin, device), *(d[k].to(device) for k in P2G_KEYS),
            grid_id.to(device), geometry, 1e-4, fields, backend="cpp")
    assert float(fields.mass.double().sum()) == pytest.approx(n, rel=1e-6)  # every particle's mass


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("case", ["one_cell", "one_block"])
def test_mpm_kernels_on_crowded_cells_match_their_twins(case, device):
    geometry, p = crowded_particles(case)
    # A low split threshold (0.05 per cell), so that the damage across a single cell splits nodes.
    fields_geo, K, dt, split_gradient = both_fields(geometry), geometry.n_grids, 1e-4, 0.05 / geometry.dx
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    twin_bins = reference.bin_particles(p["x"], p["grid_id"], geometry)
    for field in dataclasses.fields(ParticleBins):
        assert torch.equal(getattr(bins, field.name), getattr(twin_bins, field.name)), field.name
    assert len(bins.cell_key) == 2 and int(bins.cell_start[1]) == len(p["x"]) // 2  # one cell per grid
    d = {k: v.to(device) for k, v in p.items()}
    dbins = on(bins, device)

    # P2G with the damage lane, against the float64 twin.
    fields = GridFields.zeros(fields_geo, torch.device(device), with_contact=True, with_fragments=True)
    ops.p2g(dbins, *(d[k] for k in P2G_KEYS), d["grid_id"], fields_geo, dt, fields, backend="cpp",
            damaged=d["damaged"])
    twin = GridFields.zeros(fields_geo, CPU, with_contact=True, with_fragments=True)
    twin = GridFields(*(t.double() if t is not None and t.is_floating_point() else t
                        for t in (getattr(twin, f.name) for f in dataclasses.fields(GridFields))))
    reference.p2g(*(p[k].double() for k in P2G_KEYS), p["grid_id"], fields_geo, dt, twin, p["damaged"])
    for name in ("mass", "momentum", "mass_gradient", "position_moment", "damage"):
        assert rel_err(getattr(fields, name)[:K], getattr(twin, name)[:K]) < REL_TOL, name

    # The fragment passes: damage gradients, references, fields A and B (which only move mass).
    before = fields.mass[:K].double().sum().item()
    gradient = ops.fragment_reference(dbins, d["x"], d["grid_id"], geometry, 1e-12, split_gradient, fields,
                                      backend="cpp")
    twin_gradient = reference.fragment_reference(p["x"], p["grid_id"], geometry, 1e-12, split_gradient,
                                                 GridFields(*(t.cpu().clone() if t is not None else None for t in
                                                              (getattr(fields, f.name) for f in
                                                               dataclasses.fields(GridFields)))))
    assert rel_err(gradient, twin_gradient) < REL_TOL
    split_particle, split_keys, side_mask = ops.fragment_partition(
        dbins, *(d[k] for k in P2G_KEYS), d["grid_id"], geometry, dt, gradient, split_gradient, fields,
        backend="cpp")
    assert int(split_particle.sum()) > 0 and len(split_keys) > 0, "the damaged part must split nodes"
    assert fields.mass.double().sum().item() == pytest.approx(before, rel=1e-5)
    touched, contact = ops.fragment_field_blocks(bins, split_keys.cpu(), geometry)
    touched, contact = touched.to(device), contact.to(device)
    field_bins = dataclasses.replace(dbins, touched=touched, contact_blocks=contact)

    # Grid update, contact, boundaries, then G2P with the fragments, against the twins.
    ops.grid_update(field_bins, fields_geo, dt, (0.0, 0.0, -9.8), 1e-12, fields, backend="cpp")
    momentum = (fields.mass[..., None] * fields.velocity).double().sum((0, 1))
    ops.collision(field_bins, fields_geo, 1.0, 0.3, 1e-12, 0.9 * geometry.dx, fields, backend="cpp")
    after = (fields.mass[..., None] * fields.velocity).double().sum((0, 1))
    assert float((after - momentum).abs().max()) <= 1e-4 * float(momentum.abs().max())
    ops.boundaries(field_bins, fields_geo, "slip", 0.2, 0.3, 1e-12, fields, backend="cpp")
    n = len(p["x"])
    table = MaterialTable([NACCMaterial(E=1e4, nu=0.3, density=1, alpha0=-0.01, beta=0.5, xi=1, M=2.36)]).table(CPU)
    state = (p["x"], torch.eye(3).expand(n, 3, 3).contiguous(), torch.full((n,), -0.01), p["damaged"],
             p["grid_id"], torch.zeros(n, dtype=torch.int32))
    frag = FragmentFields(gradient, fields.reference, split_particle, split_gradient, side_mask)
    compiled = ops.g2p(*(t.to(device) for t in state), table.to(device), fields, geometry, dt, backend="cpp",
                       fragments=frag)
    cpu_fields = GridFields(*(t.cpu() if t is not None else None for t in
                              (getattr(fields, f.name) for f in dataclasses.fields(GridFields))))
    cpu_frag = FragmentFields(gradient.cpu(), fields.reference.cpu(), split_particle.cpu(), split_gradient)
    twin_out = ops.g2p(*state, table, cpu_fields, geometry, dt, backend="reference", fragments=cpu_frag)
    assert rel_err(compiled[1], twin_out[1]) < REL_TOL  # velocities
    assert rel_err(compiled[0], twin_out[0]) < REL_TOL  # positions
    ops.fragment_clear(touched[len(bins.touched):], fields_geo, fields, backend="cpp")
    assert float(fields.mass[K:].abs().max()) == 0.0


def test_spatial_and_fracture_kernels_on_one_huge_piece():
    """2000 points within one hash cell form one piece: every query scans all of them."""
    gen = torch.Generator().manual_seed(1)
    n, radius = 2000, 0.05
    points = (0.5 + 0.01 * torch.rand(n, 3, generator=gen)).contiguous()
    roots = spatial.component_roots(points, radius, backend="cpp")
    assert torch.equal(roots, torch.zeros(n, dtype=roots.dtype))
    assert not bool(spatial.small_component_mask(points, radius, 10, backend="cpp").any())
    index, distance = spatial.knn_within(points, points[:100], radius, 32, backend="cpp")
    twin_index, twin_distance = spatial.knn_within(points, points[:100], radius, 32, backend="reference")
    assert torch.equal(index, twin_index)
    assert float((distance - twin_distance).abs().max()) < 1e-6
    table = index.to(torch.int32).contiguous()
    rows = torch.arange(100, dtype=torch.int64)
    kept = spatial.retained_neighbours(points, rows, table, radius, backend="cpp")
    assert torch.equal(kept, spatial.retained_neighbours(points, rows, table, radius, backend="reference"))
    # Every Gaussian driven by one particle; lens ellipsoids of all pairs of one sphere cluster.
    F = (torch.eye(3) + 0.1 * torch.randn(4, 3, 3, generator=gen)).contiguous()
    driver = torch.zeros(n, dtype=torch.int64)
    args = (points[:4], F, driver, 0.01 * torch.randn(n, 3, generator=gen),
            0.001 * torch.eye(3).expand(n, 3, 3).contiguous(), torch.eye(3)[None], torch.zeros(n, dtype=torch.int32))
    compiled = fracture_ops.deform_gaussians(*args, backend="cpp")
    twin = fracture_ops.deform_gaussians(*args, backend="reference")
    for got, want in zip(compiled, twin):
        assert rel_err(got, want) < REL_TOL
    lens = fracture_ops.lens_ellipsoids(points[:-1], torch.full((n - 1,), radius), points[1:],
                                        torch.full((n - 1,), radius), backend="cpp")
    lens_twin = fracture_ops.lens_ellipsoids(points[:-1], torch.full((n - 1,), radius), points[1:],
                                             torch.full((n - 1,), radius), backend="reference")
    assert torch.equal(lens.valid, lens_twin.valid) and bool(lens.valid.all())
    assert rel_err(lens.centre, lens_twin.centre) < REL_TOL


@pytest.mark.parametrize("exclusive", [False, "groups"])
def test_rasterizer_with_every_gaussian_on_one_tile(exclusive):
    """2000 Gaussians in front of a 16x16 image (one tile): its list holds them all."""
    gen = torch.Generator().manual_seed(2)
    n = 2000
    camera = make_camera(16, 16, 0)
    scene = {"means": torch.rand(n, 3, generator=gen) - 0.5, "opacities": 0.05 + 0.3 * torch.rand(n, generator=gen),
             "scales": 0.05 + 0.2 * torch.rand(n, 3, generator=gen), "quats": torch.randn(n, 4, generator=gen),
             "colors": torch.rand(n, 3, generator=gen), "background": torch.rand(3, generator=gen)}
    if exclusive:
        scene["exclusive"] = torch.randint(-1, 300, (n,), generator=gen)
    means, opacities, kwargs = split(scene)
    leaves = means.clone().requires_grad_(True)
    cpp = rasterize(leaves, opacities, camera, backend="cpp", **kwargs)
    cpp["rgb"].sum().backward()
    twin_leaves = means.double().clone().requires_grad_(True)
    twin_kwargs = {k: (v.double() if v.is_floating_point() else v) for k, v in kwargs.items()}
    twin = rasterize_reference(twin_leaves, opacities.double(), camera, **twin_kwargs)
    twin["rgb"].sum().backward()
    assert int((cpp["radii"] > 0).sum()) == n
    assert float(twin["alpha"].detach().max()) > 0.999  # the Gaussians saturate the pixels they cover
    assert rel_err(cpp["rgb"], twin["rgb"]) < REL_TOL
    assert rel_err(leaves.grad, twin_leaves.grad) < 1e-3


@pytest.mark.parametrize("bad", ["moved_particle", "order", "touched", "contact", "reference_key"])
def test_a_violated_bound_is_one_kernel_bound_error(bad):
    geometry, p = crowded_particles("one_cell")
    fields_geo, dt = both_fields(geometry), 1e-4
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    fields = GridFields.zeros(fields_geo, CPU, with_contact=True, with_fragments=True)
    x = p["x"]
    if bad == "moved_particle":  # out of its block, still inside the grid
        x = x.clone()
        x[7] += 5 * geometry.dx
    elif bad == "order":
        bins = dataclasses.replace(bins, order=bins.order.clone())
        bins.order[3] = len(x)
    elif bad == "touched":
        bins = dataclasses.replace(bins, touched=bins.touched.clone())
        bins.touched[0] = geometry.n_grids * geometry.n_blocks
    elif bad == "contact":
        bins = dataclasses.replace(bins, contact_blocks=torch.tensor([-1], dtype=torch.int32))

    def run() -> None:
        ops.p2g(bins, x, *(p[k] for k in P2G_KEYS[1:]), p["grid_id"], fields_geo, dt, fields, backend="cpp",
                damaged=p["damaged"])
        if bad == "reference_key":  # a key naming a particle of a larger set
            fields.reference[0, int(fields.mass[0].argmax())] = (0x7F000000 << 32) | len(x)
        gradient = ops.fragment_reference(bins, x, p["grid_id"], geometry, 1e-12, 0.25 / geometry.dx, fields,
                                          backend="cpp")
        ops.fragment_partition(bins, x, *(p[k] for k in P2G_KEYS[1:]), p["grid_id"], geometry, dt, gradient,
                               0.25 / geometry.dx, fields, backend="cpp")
        ops.collision(bins, fields_geo, 1.0, 0.3, 1e-12, geometry.dx, fields, backend="cpp")

    with pytest.raises(KernelBoundError) as caught:
        run()
    message = str(caught.value)
    assert "\n" not in message and len(message) < 300
    expected = {"moved_particle": "particle 7 does not lie in the grid block", "order": "order[3]",
                "touched": "touched[0]", "contact": "contact_blocks[0] = -1", "reference_key": "reference key"}
    assert expected[bad] in message


SCENE = """\
name: crowded
domain: {min: [0, 0, 0], max: [1, 1, 1], grid: 16}
frames: 2
frame_dt: 0.001
gravity: [0, 0, -9.8]
contact: {mode: collision, fragments: true}
boundaries:
  - {type: ground, height: 0.2, friction: 0.5}
objects:
  - name: box
    primitive: {shape: box, size: [0.1, 0.1, 0.1], particles_per_cell: 500}
    transform: {translate: [0.5, 0.5, 0.4]}
    velocity: [0, 0, -2]
    materials:
      - {part: 0, model: elastic, E: 1.0e4, nu: 0.3, density: 100}
"""

def test_simulate_reports_a_violated_bound_in_one_line_with_exit_1(tmp_path, monkeypatch, capsys):
    """simulate.py on a scene of 500 particles per cell, with P2G handed bins in which particle 5
    was sorted one block away from its stencil (as a binning bug would do)."""
    from fracture_gs.cli.simulate import main

    binned = ops.bin_particles

    def misbinned(x, grid_id, geometry, backend="auto"):
        moved = x.clone()
        moved[5, 0] += 4 * geometry.dx
        return binned(moved, grid_id, geometry, backend)

    monkeypatch.setattr(ops, "bin_particles", misbinned)
    scene = tmp_path / "crowded.yaml"
    scene.write_text(SCENE)
    assert main(["--scene", str(scene), "--out", str(tmp_path / "sim")]) == 1
    stderr = capsys.readouterr().err
    lines = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    assert "a kernel refused its input while computing frame 1" in lines[0]
    assert "does not lie in the grid block it was sorted into" in lines[0]
    assert "frames 0..0" in lines[0]
    # The scene's 500 particles per cell are above what the solver is built for: warned first.
    assert "particles in a cell of this 16-cell grid" in stderr
    assert "domain.grid >=" in stderr
