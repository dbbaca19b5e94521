"""The Gaussians of frame t of a simulation — the one implementation that ``render.py``, the
viewer and ``evaluate.py`` share.

```python
sim = Simulation.open("output/sims/teapot_ground")
scene = SceneGaussians.from_simulation(sim, device)         # once: binds particles to Gaussians
gaussians = scene.frame(sim.load_frame(40, device))        # FPGO on (fpgo=False: baseline)
image = gaussians.rasterize(camera, background)["rgb"]
gaussians.write_ply("frame_00040.ply")                     # any 3DGS viewer opens it
```

Binding (built once): an object with a trained ``model`` folder draws the Gaussians of its
newest ``point_cloud/iteration_N/point_cloud.ply`` that its particles reference
(``gaussian_index``), each once, driven by the nearest particle that references it; the scene
transform moves them into the world (means, covariances s²RΣRᵀ, SH through the view rotation).
A primitive object (or a bare particles ``.ply``) draws one isotropic Gaussian of scale
spacing / 2 per surface particle, in a flat colour per object. Particles without a Gaussian get
an appearance interpolated from the nearest surface Gaussians (for FPGO).

Per frame: Σ_t = F_E Σ₀ F_Eᵀ, mean = x + F_E · rest offset, SH looked up at (R R_obj)ᵀ·dir with
R the polar rotation of F_E (docs/formulas.md §12) — compiled kernels — then optionally FPGO
(:mod:`fracture_gs.fracture.fpgo`).

Frame PLY files follow the 3DGS layout: covariances become scale + rotation, SH are rotated
into the world frame, and FPGO's exclusive group (id + 1, 0 for none) travels in the ``nx``
column, ``ny`` = 1 when the global rule applies (3DGS writes zeros there and no renderer
reads normals), so viewers that read fixed-size rows open it too.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from fracture_gs.config.scene import ObjectConfig
from fracture_gs.folders.model_folder import estimated_spacing, model_spacing
from fracture_gs.folders.sim_reader import SimFrame, Simulation
from fracture_gs.fracture.fpgo import (FPGOSettings, FPGOStats, FractureParticles, apply_fpgo,
                                       contiguous_span, rest_neighbour_tables)
from fracture_gs.fracture.ops import deform_gaussians
from fracture_gs.fracture.spatial import k_nearest
from fracture_gs.gaussians import GaussianModel, PlyFormatError, read_ply, rgb_to_sh_dc, write_ply
from fracture_gs.io.model_layout import ModelError, latest_point_cloud
from fracture_gs.mpm.scene import rotation_matrix_xyz
from fracture_gs.render.camera import Camera
from fracture_gs.render.rasterize import rasterize
from fracture_gs.render.sh_rotation import rotate_sh

FLAT_PALETTE = ((0.86, 0.42, 0.30), (0.27, 0.51, 0.78), (0.38, 0.70, 0.40), (0.93, 0.72, 0.25),
                (0.62, 0.45, 0.75), (0.35, 0.75, 0.78), (0.80, 0.50, 0.62), (0.55, 0.55, 0.55))
FLAT_OPACITY = 0.95


# ----------------------------------------------------------------------------- FrameGaussians

# the per-Gaussian tensors of a FrameGaussians (FPGO takes and returns them as a dict)
GAUSSIAN_COLUMNS = ("means", "covariances", "opacities", "sh", "view_rotations", "exclusive",
                    "object_id", "is_fpgo", "particle")

@dataclass
class FrameGaussians:
    """The Gaussians of one frame, world frame, ready for :func:`fracture_gs.render.rasterize`.

    SH coefficients are in each object's model frame and are looked up at
    ``view_rotations[g]ᵀ · direction``; ``exclusive`` is the exclusive group of FPGO lens
    Gaussians (the fractured particle whose Gaussian they replace; -1: none) and
    ``exclusive_rule`` how it applies (``fracture_gs.render.exclusive``: "group", only the nearest
    lens of each group blends at a pixel; "all", only the nearest of all lenses); ``particle`` is
    the particle each Gaussian follows.
    """

    means: torch.Tensor           # (M,3)
    covariances: torch.Tensor     # (M,3,3)
    opacities: torch.Tensor       # (M,) in [0,1]
    sh: torch.Tensor              # (M,K,3)
    view_rotations: torch.Tensor  # (M,3,3)
    exclusive: torch.Tensor       # (M,) int64 exclusive group, -1: none
    object_id: torch.Tensor       # (M,) int32
    is_fpgo: torch.Tensor         # (M,) bool: made by FPGO (lens or interior Gaussian)
    particle: torch.Tensor        # (M,) int64
    stats: FPGOStats | None = None
    exclusive_rule: str = "group"  # "group" or "all" (the global rule of docs/formulas.md §11)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def columns(self) -> dict[str, torch.Tensor]:
        """The per-Gaussian tensors by name (:data:`GAUSSIAN_COLUMNS`)."""
        return {name: getattr(self, name) for name in GAUSSIAN_COLUMNS}

    def select(self, mask: torch.Tensor) -> "FrameGaussians":
        """The Gaussians where ``mask`` (bool or indices) selects."""
        return replace(self, **{name: getattr(self, name)[mask] for name in GAUSSIAN_COLUMNS})

    def rasterize(self, camera: Camera, background: torch.Tensor | None = None,
                  backend: str = "auto") -> dict[str, torch.Tensor]:
        """Render with :func:`fracture_gs.render.rasterize` (rgb, alpha, depth, radii)."""
        with torch.no_grad():
            return rasterize(self.means, self.opacities, camera, covariances=self.covariances,
                             sh=self.sh, view_rotations=self.view_rotations,
                             exclusive=self.exclusive_argument(),
                             background=background, backend=backend)

    def exclusive_argument(self) -> torch.Tensor | None:
        """``exclusive`` for :func:`fracture_gs.render.rasterize`: group ids, bool flags for the
        global rule, None when no Gaussian is exclusive."""
        flags = self.exclusive >= 0
        if not bool(flags.any()):
            return None
        return flags if self.exclusive_rule == "all" else self.exclusive

    def without_exclusive(self) -> "FrameGaussians":
        """The same Gaussians, all blending like ordinary ones."""
        return replace(self, exclusive=torch.full_like(self.exclusive, -1))

    def to_gaussian_model(self) -> GaussianModel:
        """The same Gaussians as a 3DGS model: scale + rotation from the eigen-decomposition of
        each covariance, SH rotated into the world frame (no view rotation needed), opacity
        logits. On the CPU, float32."""
        covariances = self.covariances.detach().double().cpu()
        covariances = 0.5 * (covariances + covariances.transpose(1, 2))
        eigenvalues, eigenvectors = torch.linalg.eigh(covariances)
        flip = torch.linalg.det(eigenvectors) < 0
        eigenvectors[flip, :, 2] *= -1.0
        log_scales = 0.5 * torch.log(eigenvalues.clamp_min(1e-30))
        from scipy.spatial.transform import Rotation

        xyzw = Rotation.from_matrix(eigenvectors.numpy()).as_quat() if len(self) else np.zeros((0, 4))
        quats = torch.from_numpy(np.ascontiguousarray(xyzw[:, [3, 0, 1, 2]]))
        sh = rotate_sh(self.sh.detach().double().cpu(), self.view_rotations.detach().double().cpu())
        opacity = self.opacities.detach().double().cpu().clamp(1e-6, 1.0 - 1e-6)
        logit = torch.log(opacity / (1.0 - opacity))
        return GaussianModel(self.means.detach().float().cpu(), sh[:, :1].float(), sh[:, 1:].float(),
                             logit[:, None].float(), log_scales.float(), quats.float())

    def write_ply(self, path: str | Path) -> None:
        """Write a 3DGS ``point_cloud.ply`` (atomically); ``nx`` holds the exclusive group + 1,
        ``ny`` is 1 under the global rule."""
        if len(self) and int(self.exclusive.max()) + 1 >= 2 ** 24:
            raise ValueError(f"write_ply({path}): exclusive group ids must stay below 2**24 - 1 "
                             "to travel exactly in the float32 nx column")
        normals = torch.zeros(len(self), 3, dtype=torch.float64)
        normals[:, 0] = self.exclusive.detach().cpu().double() + 1.0
        normals[:, 1] = 1.0 if self.exclusive_rule == "all" else 0.0
        write_ply(str(path), self.to_gaussian_model(), normals=normals)


def read_frame_ply(path: str | Path,
                   device: torch.device | None = None) -> tuple[GaussianModel, torch.Tensor]:
    """A PLY written by :meth:`FrameGaussians.write_ply`: the model and its ``exclusive`` in the
    form :func:`fracture_gs.render.rasterize` takes (int64 group ids, -1 for none; bool flags
    when the frame was drawn with the global rule)."""
    import plyfile

    model = read_ply(str(path), device=device)
    vertex = plyfile.PlyData.read(str(path))["vertex"]
    names = [p.name for p in vertex.properties]
    groups = (np.rint(np.asarray(vertex["nx"], np.float64)).astype(np.int64) - 1
              if "nx" in names else np.full(vertex.count, -1, np.int64))
    global_rule = "ny" in names and vertex.count > 0 and bool(np.asarray(vertex["ny"]).max() > 0.5)
    exclusive = torch.from_numpy(groups >= 0 if global_rule else groups)
    return model, exclusive.to(model.device)


# ----------------------------------------------------------------------------- the binding


@dataclass
class _ObjectTable:
    """One object's drawable Gaussians at rest (world frame) and its particle bookkeeping."""

    driver: np.ndarray           # (M,) global particle index
    rest_offset: np.ndarray      # (M,3)
    rest_covariance: np.ndarray  # (M,3,3)
    opacity: np.ndarray          # (M,)
    sh: np.ndarray               # (M,K,3)
    own_particles: np.ndarray    # particles that have an own Gaussian
    own_rows: np.ndarray         # their row in this table
    own_sigma: np.ndarray        # rest size of those Gaussians (geometric mean of the scales)
    spacing: float


def _object_transform(obj: ObjectConfig) -> tuple[np.ndarray, float, np.ndarray]:
    rotation = rotation_matrix_xyz(obj.transform.rotate_deg)
    return rotation, float(obj.transform.scale), np.asarray(obj.transform.translate, np.float64)


def _trained_table(sim: Simulation, index: int, rows: np.ndarray) -> _ObjectTable:
    obj = sim.scene.objects[index]
    assert obj.model is not None
    ply = latest_point_cloud(obj.model)
    try:
        model = read_ply(str(ply))
    except PlyFormatError as exc:
        raise ModelError(str(exc)) from None
    rotation, scale, translate = _object_transform(obj)
    with torch.no_grad():
        means = model.means.double().numpy()
        covariances = model.covariances().double().numpy()
        opacity = model.opacities.double().numpy()
        sh = model.sh.float().numpy()
        sigma_model = torch.exp(model.log_scales.double()).expand(-1, 3).prod(1).pow(1 / 3).numpy()
    means_world = translate + scale * means @ rotation.T
    cov_world = scale * scale * np.einsum("ij,njk,lk->nil", rotation, covariances, rotation)
    rest_x = sim.particles.rest_x.astype(np.float64)
    index_of = sim.particles.gaussian_index[rows]
    bound = index_of >= 0
    if not bound.any():
        raise ModelError(f"{sim.root}/particles.npz: no particle of object '{obj.name}' is bound "
                         f"to a Gaussian of {ply} (gaussian_index is -1 everywhere)")
    if index_of.max() >= means.shape[0]:
        raise ModelError(f"{sim.root}/particles.npz: object '{obj.name}' references Gaussian "
                         f"{int(index_of.max())}, but {ply} has {means.shape[0]}")
    particles, gaussians = rows[bound], index_of[bound]
    distance = np.linalg.norm(rest_x[particles] - means_world[gaussians], axis=1)
    order = np.lexsort((particles, distance, gaussians))   # by Gaussian, then distance
    first = np.ones(order.shape[0], dtype=bool)
    first[1:] = gaussians[order][1:] != gaussians[order][:-1]
    drawn = gaussians[order][first]                         # ascending Gaussian index
    driver = particles[order][first]
    spacing = model_spacing(obj.model)
    spacing = spacing * scale if spacing is not None else estimated_spacing(rest_x[rows])
    return _ObjectTable(driver=driver, rest_offset=means_world[drawn] - rest_x[driver],
                        rest_covariance=cov_world[drawn], opacity=opacity[drawn], sh=sh[drawn],
                        own_particles=particles, own_rows=np.searchsorted(drawn, gaussians),
                        own_sigma=scale * sigma_model[gaussians], spacing=spacing)


def _flat_table(sim: Simulation, index: int, rows: np.ndarray) -> _ObjectTable:
    obj = sim.scene.objects[index]
    if obj.primitive is not None:
        spacing = float(np.cbrt(np.median(sim.particles.rest_volume[rows])))
    else:
        spacing = model_spacing(obj.model.parent if obj.model and obj.model.is_file() else obj.model)
        rest = sim.particles.rest_x[rows].astype(np.float64)
        spacing = spacing * obj.transform.scale if spacing is not None else estimated_spacing(rest)
    surface = rows[sim.particles.is_surface[rows]]
    drawn = surface if surface.size else rows
    count = drawn.shape[0]
    sigma = 0.5 * spacing
    colour = torch.tensor(FLAT_PALETTE[index % len(FLAT_PALETTE)])
    sh = np.broadcast_to(rgb_to_sh_dc(colour).numpy(), (count, 1, 3)).astype(np.float32)
    return _ObjectTable(driver=drawn, rest_offset=np.zeros((count, 3)),
                        rest_covariance=np.broadcast_to(sigma * sigma * np.eye(3), (count, 3, 3)),
                        opacity=np.full(count, FLAT_OPACITY), sh=sh, own_particles=drawn,
                        own_rows=np.arange(count), own_sigma=np.full(count, sigma), spacing=spacing)


def _interpolated_appearance(rest_x: np.ndarray, table: _ObjectTable, queries: np.ndarray,
                             k: int) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-distance opacity and SH of the k nearest drawn Gaussians (rest configuration)."""
    if queries.size == 0:
        return np.zeros(0), np.zeros((0,) + table.sh.shape[1:], np.float32)
    centres = rest_x[table.driver] + table.rest_offset
    k = min(k, centres.shape[0])
    if k <= 16:   # hash grid: a k-d tree of surface samples is slow from deep inside the body
        nearest = k_nearest(torch.from_numpy(centres), torch.from_numpy(rest_x[queries]), k,
                            2.0 * table.spacing).numpy()
        distance = np.linalg.norm(centres[nearest] - rest_x[queries][:, None], axis=2)
    else:
        from scipy.spatial import cKDTree

        distance, nearest = cKDTree(centres).query(rest_x[queries], k=k)
        distance, nearest = distance.reshape(queries.size, k), nearest.reshape(queries.size, k)
    weight = 1.0 / np.maximum(distance, 1e-12)
    weight /= weight.sum(axis=1, keepdims=True)
    opacity = (weight * table.opacity[nearest]).sum(axis=1)
    sh = np.einsum("qk,qkcd->qcd", weight, table.sh[nearest]).astype(np.float32)
    return opacity, sh


def _pad_sh(sh: np.ndarray, coefficients: int) -> np.ndarray:
    if sh.shape[1] == coefficients:
        return sh
    out = np.zeros((sh.shape[0], coefficients, 3), np.float32)
    out[:, :sh.shape[1]] = sh
    return out


def _paint_interior(sim: Simulation, interior: np.ndarray, interior_sh: np.ndarray) -> None:
    """Give the interior particles of parts with an ``interior_colour`` that flat colour (SH degree
    0 only) instead of the one interpolated from the surface: the faces a fracture opens in
    porcelain are white whatever its glaze."""
    painted = [(index, material.part, material.interior_colour)
               for index, obj in enumerate(sim.scene.objects) for material in obj.materials
               if material.interior_colour is not None]
    if not painted or interior.size == 0:
        return
    part_id = sim.particles.part_id if sim.particles.part_id is not None else np.zeros(len(sim.particles), np.int32)
    for index, part, colour in painted:
        members = (sim.particles.obj_id[interior] == index) & (part_id[interior] == part)
        interior_sh[members] = 0.0
        interior_sh[members, 0] = rgb_to_sh_dc(np.asarray(colour, np.float32))


def _fracture_arrays(sim: Simulation, tables: list[_ObjectTable], coefficients: int,
                     interpolation_k: int) -> dict[str, np.ndarray]:
    """Per-particle arrays of :class:`FractureParticles` (own Gaussian, sphere centre Gaussian,
    rest size, and the interpolated appearance of particles without a Gaussian)."""
    count = len(sim.particles)
    rest_x = sim.particles.rest_x.astype(np.float64)
    own_gaussian = np.full(count, -1, dtype=np.int64)
    rest_sigma = np.zeros(count)
    offset = 0
    for index, table in enumerate(tables):
        rest_sigma[sim.particles.obj_id == index] = 0.5 * table.spacing
        own_gaussian[table.own_particles] = offset + table.own_rows
        rest_sigma[table.own_particles] = table.own_sigma
        offset += table.driver.shape[0]
    driver = np.concatenate([t.driver for t in tables])
    with_own = np.nonzero(own_gaussian >= 0)[0]
    drives_own = with_own[driver[own_gaussian[with_own]] == with_own]
    centre_gaussian = np.full(count, -1, dtype=np.int64)
    centre_gaussian[drives_own] = own_gaussian[drives_own]
    interior = np.nonzero(own_gaussian < 0)[0]
    interior_row = np.full(count, -1, dtype=np.int64)
    interior_row[interior] = np.arange(interior.size)
    interior_opacity = np.zeros(interior.size, np.float32)
    interior_sh = np.zeros((interior.size, coefficients, 3), np.float32)
    for index, table in enumerate(tables):
        members = np.nonzero(sim.particles.obj_id[interior] == index)[0]
        opacity, sh = _interpolated_appearance(rest_x, table, interior[members], interpolation_k)
        interior_opacity[members] = opacity
        interior_sh[members] = _pad_sh(sh, coefficients)
    _paint_interior(sim, interior, interior_sh)
    return {"own_gaussian": own_gaussian, "centre_gaussian": centre_gaussian,
            "interior_row": interior_row, "interior_opacity": interior_opacity,
            "interior_sh": interior_sh, "rest_sigma": rest_sigma.astype(np.float32)}


class SceneGaussians:
    """All drawable Gaussians of a simulation at rest, bound to its particles (build once with
    :meth:`from_simulation`, then call :meth:`frame` for each frame)."""

    def __init__(self, tables: dict[str, torch.Tensor], fracture: FractureParticles,
                 settings: FPGOSettings, object_names: list[str], sources: list[str]) -> None:
        self._tables = tables
        self.fracture = fracture
        self.settings = settings
        self.object_names = object_names
        self.sources = sources  # per object: the PLY it draws, or "flat colour"

    @property
    def num_gaussians(self) -> int:
        """Gaussians drawn without FPGO."""
        return int(self._tables["driver"].shape[0])

    @property
    def device(self) -> torch.device:
        return self._tables["driver"].device

    @classmethod
    def from_simulation(cls, sim: Simulation, device: torch.device | None = None,
                        settings: FPGOSettings | None = None) -> "SceneGaussians":
        """Bind every object's Gaussians to the particles of ``sim`` (ModelError naming the
        folder when a model cannot be used)."""
        device = device if device is not None else torch.device("cpu")
        settings = settings if settings is not None else FPGOSettings()
        if len(sim.particles) >= 2 ** 31 - 1:
            raise ModelError(f"{sim.root}/particles.npz: {len(sim.particles)} particles exceed "
                             "the int32 indices of the neighbour kernels")
        tables, sources = [], []
        for index, obj in enumerate(sim.scene.objects):
            rows = np.nonzero(sim.particles.obj_id == index)[0]
            if rows.size == 0:
                raise ModelError(f"{sim.root}/particles.npz: object '{obj.name}' has no particles")
            trained = obj.model is not None and obj.model.is_dir()
            tables.append(_trained_table(sim, index, rows) if trained else
                          _flat_table(sim, index, rows))
            sources.append(str(latest_point_cloud(obj.model)) if trained else "flat colour")
        coefficients = max(t.sh.shape[1] for t in tables)

        def tensor(array: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(array)).to(device=device, dtype=dtype)

        table_columns = {
            "driver": tensor(np.concatenate([t.driver for t in tables]), torch.int64),
            "rest_offset": tensor(np.concatenate([t.rest_offset for t in tables]), torch.float32),
            "rest_covariance": tensor(np.concatenate([t.rest_covariance for t in tables]),
                                      torch.float32),
            "opacities": tensor(np.concatenate([t.opacity for t in tables]), torch.float32),
            "sh": tensor(np.concatenate([_pad_sh(t.sh, coefficients) for t in tables]),
                         torch.float32),
            "object_id": tensor(np.concatenate([np.full(t.driver.shape[0], i)
                                                for i, t in enumerate(tables)]), torch.int32),
        }
        arrays = _fracture_arrays(sim, tables, coefficients, settings.interpolation_k)
        rotations = np.stack([_object_transform(obj)[0] for obj in sim.scene.objects])
        obj_id = sim.particles.obj_id
        rows_by_object = [tensor(np.nonzero(obj_id == o)[0], torch.int64)
                          for o in range(len(tables))]
        rest_neighbours, rest_counts = rest_neighbour_tables(
            tensor(sim.particles.rest_x, torch.float32), rows_by_object,
            [settings.dc_factor * t.spacing for t in tables])
        fracture = FractureParticles(
            **{name: tensor(value, torch.float32 if value.dtype.kind == "f" else torch.int64)
               for name, value in arrays.items()},
            object_id=tensor(obj_id, torch.int64),
            object_spacing=torch.as_tensor([t.spacing for t in tables], dtype=torch.float64),
            object_rotation=tensor(rotations, torch.float32),
            rows_by_object=rows_by_object, rest_neighbours=rest_neighbours,
            rest_neighbour_count=rest_counts,
            object_slices=[contiguous_span(rows) for rows in rows_by_object])
        return cls(table_columns, fracture, settings, sim.object_names, sources)

    def _deform_interior(self, x: torch.Tensor, F_E: torch.Tensor, backend: str):
        """Deformation of the interpolated Gaussians (isotropic, spacing/2) of particles."""
        fracture = self.fracture

        def deform(rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            objects = fracture.object_id[rows]
            sigma = 0.5 * fracture.object_spacing.to(x.device, torch.float32)[objects]
            covariance = sigma[:, None, None] ** 2 * torch.eye(3, device=x.device)
            return deform_gaussians(x, F_E, rows, torch.zeros(rows.shape[0], 3, device=x.device),
                                    covariance, fracture.object_rotation, objects, backend=backend)

        return deform

    def frame(self, frame: SimFrame, fpgo: bool = True, backend: str = "auto") -> FrameGaussians:
        """The Gaussians to draw at ``frame`` (with FPGO unless ``fpgo`` is False); ``stats``
        holds what FPGO did (None without FPGO)."""
        tables = self._tables
        x, F_E = frame.x.to(self.device), frame.F_E.to(self.device)
        deformed = deform_gaussians(x, F_E, tables["driver"], tables["rest_offset"],
                                    tables["rest_covariance"], self.fracture.object_rotation,
                                    tables["object_id"], backend=backend)
        count = self.num_gaussians
        base = FrameGaussians(
            means=deformed.means, covariances=deformed.covariances, opacities=tables["opacities"],
            sh=tables["sh"], view_rotations=deformed.view_rotations,
            exclusive=torch.full((count,), -1, dtype=torch.int64, device=self.device),
            object_id=tables["object_id"], is_fpgo=torch.zeros(count, dtype=torch.bool,
                                                               device=self.device),
            particle=tables["driver"])
        if not fpgo:
            return base
        columns, stats = apply_fpgo(base.columns(), x, F_E, frame.fractured.to(self.device), self.fracture,
                                    self.settings, self._deform_interior(x, F_E, backend), backend)
        rule = "all" if self.settings.exclusive == "all" else "group"
        return FrameGaussians(**columns, stats=stats, exclusive_rule=rule)


__all__ = ["FLAT_PALETTE", "FrameGaussians", "ModelError", "SceneGaussians", "latest_point_cloud",
           "read_frame_ply"]
