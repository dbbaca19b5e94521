"""Collision-MPM solver: MLS-MPM with per-object grids and momentum-conserving contact.

One substep (docs/formulas.md §2–§9):
    bins → P2G (per object grid) → [fragments: damage gradients, split nodes, fields A/B] →
    grid update (+gravity) → contact pass → boundaries → G2P (+ return map, fracture flag)
The state is only replaced once the new one is finite and plausible, so a blow-up never
corrupts what has been written so far.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np
import torch

from fracture_gs.mpm import ops
from fracture_gs.mpm.fragments import count_fragments, fragment_ids, object_link_radii
from fracture_gs.mpm.impulse import ExternalImpulse
from fracture_gs.mpm.grid import FragmentFields, G2PStats, GridFields, GridGeometry, ParticleBins
from fracture_gs.materials import COLUMN, MaterialTable, SubstepView, elastic_energy
from fracture_gs.mpm.ordering import inverse_permutation, spatial_order
from fracture_gs.mpm.rigid import ContactPlane, RigidBodies
from fracture_gs.mpm.types import (BoxBoundary, ContactSettings, Domain, GroundBoundary, ParticleSet, SimState,
                                   SimulationBlowUp, StepStats)

STATE_KEYS = ("x", "v", "C", "F_E", "material_state", "fractured", "stress")
# A particle's split direction (fracture_gs.materials.MaterialTable.split_directions) outranks damage
# gradients as a node reference: its reference vector is the direction times this many 1/cells
# (split nodes need split_gradient, 0.25 per cell by default).
SPLIT_DIRECTION_CELLS = 4.0
# Substeps over which dissipated energy densities add up per particle in float32 before they reach
# the float64 per-object sums (relative round-off of the float32 sums below 50 * 6e-8).
DISSIPATION_FLUSH_STEPS = 50


class CollisionMPM:
    """Multi-body MLS-MPM simulator (collision mode) or the shared-grid baseline (mls mode).

    Particle order: the compiled transfers are fastest when each grid block's particles are
    neighbours in memory (:mod:`fracture_gs.mpm.ordering`). ``build_scene`` hands the particles
    over in that order, and every ``reorder_every`` substeps (0: never) the solver sorts its
    particles again, since they drift apart as bodies deform and break. ``particles``, ``state``
    and ``stress`` are always in the solver's current order (``input_index[i]`` is the row of
    particle ``i`` in the ParticleSet given to the constructor); :meth:`state_in_input_order`
    gives the state in the constructor's order, as frames are written.
    """

    def __init__(self, particles: ParticleSet, materials: Sequence, domain: Domain, *,
                 contact: ContactSettings | None = None, boundaries: Sequence = (),
                 gravity: Sequence[float] = (0.0, 0.0, -9.8), cfl: float = 0.3,
                 object_names: Sequence[str] | None = None, backend: str = "auto",
                 device: torch.device | None = None, reorder_every: int = 50, seed: int = 0,
                 rigid_objects: Sequence[int] = ()) -> None:
        self.device = device if device is not None else particles.x.device
        self.particles = particles.to(self.device)
        self.input_particles = self.particles  # the constructor's order, kept for checkpoints
        if int(reorder_every) < 0:
            raise ValueError(f"reorder_every must be >= 0, got {reorder_every}")
        self.reorder_every = int(reorder_every)
        self.input_index = torch.arange(len(self.particles), device=self.device)
        self.materials = list(materials)
        self.domain = domain
        self.contact = contact if contact is not None else ContactSettings()
        self.gravity = tuple(float(g) for g in gravity)
        self.cfl = float(cfl)
        self.backend = backend
        n_objects = int(self.particles.obj_id.max()) + 1 if len(self.particles) else 0
        self.object_names = list(object_names) if object_names is not None else [f"object{i}" for i in range(n_objects)]
        if len(self.object_names) < n_objects:
            raise ValueError(f"{n_objects} objects but {len(self.object_names)} names")
        self.n_objects = len(self.object_names)
        self._parse_boundaries(boundaries)

        table = MaterialTable(self.materials, cell_size=domain.dx)
        self.table = table
        self.material_table = table.table(self.device)
        if int(self.particles.material_id.max()) >= len(self.materials) or int(self.particles.material_id.min()) < 0:
            raise ValueError("ParticleSet.material_id refers to a material that does not exist")
        if any(not 0 <= int(i) < self.n_objects for i in rigid_objects):
            raise ValueError(f"rigid_objects {list(rigid_objects)} name objects outside 0..{self.n_objects - 1}")

        collision_mode = self.contact.mode == "collision"
        self.n_grids = self.n_objects if collision_mode else 1
        self.geometry = GridGeometry.from_domain(domain, self.n_grids)
        # Rigid objects (fracture_gs.mpm.rigid) move as one body; their wave speed sets no time step.
        self.rigid = RigidBodies(rigid_objects, self.particles.x, self.particles.mass, self.particles.obj_id,
                                 domain.dx, self._contact_planes())
        rigid_ids = torch.tensor(self.rigid.objects, dtype=self.particles.obj_id.dtype, device=self.device)
        deforming = ~torch.isin(self.particles.obj_id, rigid_ids)
        rows = torch.unique(self.particles.material_id[deforming]).tolist()
        self.max_wave_speed = max((float(self.materials[row].wave_speed) for row in rows), default=0.0)
        self.grid_id = self._grid_ids(self.particles)
        self.use_contact = collision_mode and self.n_grids >= 2
        # Fragments (docs/formulas.md §8): each grid g gets a second field, grid n_grids + g, for the other
        # side of a crack; the field kernels then run on all 2 n_grids grids.
        self.fragments = bool(self.contact.fragments)
        self.field_geometry = (dataclasses.replace(self.geometry, n_grids=2 * self.n_grids) if self.fragments
                               else self.geometry)
        self.split_gradient = self.contact.split_gradient / self.geometry.dx  # a gradient, 1/length
        self.grid = GridFields.zeros(self.field_geometry, self.device, with_contact=self.use_contact,
                                     with_fragments=self.fragments)
        self._split_particle: torch.Tensor | None = None  # (N) 1: read a split node in the latest substep
        self._damage_started = False  # some particle's fracture flag is set (flags latch: stays True)
        # State field 0 from which a particle of each material counts as damaged for the partition (inf:
        # never), and from which it is a piece of its own (inf: never).
        self.damage_alpha = table.partition_thresholds(self.contact.damage_dilation, self.device)
        self._damage_threshold: tuple[ParticleSet, torch.Tensor] | None = None  # damage_alpha per particle
        self.piece_threshold = table.piece_thresholds(self.device)
        self.seed = int(seed)
        # The models of the scene with their materials, whether any of them dissipates energy, and the
        # energy their updates have dissipated (float64, per object): the substeps' densities add up
        # per particle (float32, current order) and reach the per-object sums every
        # DISSIPATION_FLUSH_STEPS substeps, at each re-sort and whenever they are read.
        self._models = table.models()
        self._dissipates = any(cls.dissipates for cls, _ in self._models)
        self._dissipated_total = torch.zeros(self.n_objects, dtype=torch.float64, device=self.device)
        self._dissipated_pending: torch.Tensor | None = None
        self._model_particles: dict[type, torch.Tensor] = {}   # per model: bool (N,) in the current order
        self._model_cache: dict[type, dict] = {}               # per model: its after_substep cache
        self.fragment_radius = object_link_radii(self.particles.rest_volume, self.particles.obj_id, self.n_objects)
        self._fragment_cache: tuple[int, torch.Tensor] | None = None  # (step, labels in input order)
        self.max_contact_gap = self.contact.max_gap * self.geometry.dx  # a length (inf: no check)
        self.mass_eps = 1e-12 * float(self.particles.mass.mean()) if len(self.particles) else 0.0
        self.external_impulse = ExternalImpulse(self.field_geometry, self.wall_condition, self.ground_height,
                                                self.gravity, float(self.particles.mass.double().sum()),
                                                self.device)
        self.state = self._initial_state()
        # Bins of the latest substep (diagnostics; `order` indexes the particle order of that substep).
        self.last_bins: ParticleBins | None = None
        self.max_speed = float(self.state.v.norm(dim=1).max()) if len(self.particles) else 0.0

    # ------------------------------------------------------------------ set-up
    def _parse_boundaries(self, boundaries: Sequence) -> None:
        self.wall_condition = "none"
        self.ground_height: float | None = None
        self.ground_friction = 0.0
        for boundary in boundaries:
            if isinstance(boundary, BoxBoundary):
                self.wall_condition = boundary.condition
            elif isinstance(boundary, GroundBoundary):
                self.ground_height = float(boundary.height)
                self.ground_friction = float(boundary.friction)
            else:
                raise TypeError(f"unknown boundary {boundary!r}")

    def _contact_planes(self) -> list[ContactPlane]:
        """The planes rigid bodies stay on one side of: the ground (its friction) and the faces
        particles are clamped to, the walls' inner faces (frictionless, sticky walls: no sliding);
        the floor's face only where no ground lies above it."""
        lower, upper = self.geometry.clamp_bounds()
        wall_friction = math.inf if self.wall_condition == "sticky" else 0.0
        planes = []
        for axis in range(3):
            normal = tuple(1.0 if i == axis else 0.0 for i in range(3))
            if not (axis == 2 and self.ground_height is not None and self.ground_height >= lower[axis]):
                planes.append(ContactPlane(normal, lower[axis], wall_friction))  # type: ignore[arg-type]
            planes.append(ContactPlane(tuple(-n for n in normal), -upper[axis], wall_friction))  # type: ignore[arg-type]
        if self.ground_height is not None:
            planes.append(ContactPlane((0.0, 0.0, 1.0), self.ground_height, self.ground_friction))
        return planes

    def _grid_ids(self, particles: ParticleSet) -> torch.Tensor:
        """Grid of each particle: its object's (collision mode) or the shared grid 0 (mls)."""
        if self.contact.mode == "collision":
            return particles.obj_id.to(torch.int32).contiguous()
        return torch.zeros_like(particles.obj_id, dtype=torch.int32)

    def _initial_state(self) -> SimState:
        n = len(self.particles)
        eye = torch.eye(3, device=self.device).expand(n, 3, 3).contiguous()
        material_state = self.table.initial_state(self.particles.material_id, self.particles.rest_volume,
                                                  self.seed).contiguous()
        threshold = self.material_table[self.particles.material_id.long(), COLUMN["fracture_threshold"]]
        state = SimState(x=self.particles.x.float().contiguous(), v=self.particles.v.float().contiguous(),
                         C=torch.zeros(n, 3, 3, device=self.device), F_E=eye, material_state=material_state,
                         fractured=(material_state[:, 0] >= threshold).contiguous())
        self.stress = torch.zeros(n, 3, 3, device=self.device)
        return state

    # ------------------------------------------------------------------ stepping
    @property
    def last_split_particles(self) -> int:
        """Particles whose stencil reached a split node in the latest substep (0 without fragments)."""
        return int(self._split_particle.sum()) if self._split_particle is not None else 0

    @property
    def last_split_mask(self) -> torch.Tensor | None:
        """(N) uint8: 1 where the particle's stencil reached a split node in the latest substep, or
        None (no node split). Cheaper to keep than ``last_split_particles`` inside a timed loop."""
        return self._split_particle

    def damaged(self) -> torch.Tensor:
        """(N) bool, solver order: the particles the fragment partition treats as damaged (D_p = 1),
        those whose current α is at least their material's fracture threshold plus
        ``contact.damage_dilation`` (cohesion gone and the material opened; never for elastic
        materials). Unlike the latched ``fractured`` flag this follows the state: NACC's cohesion
        returns where compaction lowers α again."""
        cached = self._damage_threshold
        if cached is None or cached[0] is not self.particles:  # per particle, for the current order
            cached = self._damage_threshold = (self.particles,
                                               torch.index_select(self.damage_alpha, 0, self.particles.material_id))
        return (self.state.alpha >= cached[1]).contiguous()

    def stable_dt(self) -> float:
        """CFL time step: cfl * dx / (c_max + |v|_max), c_max over the deforming objects' materials.
        A scene of resting rigid bodies alone has neither speed: its step is the time gravity takes to
        bring a body to sqrt(|g| dx) (inf without gravity)."""
        speed = self.max_wave_speed + self.max_speed
        if speed <= 0.0:
            speed = math.sqrt(math.hypot(*self.gravity) * self.geometry.dx)
        return self.cfl * self.geometry.dx / speed if speed > 0.0 else math.inf

    def step(self, dt: float) -> int:
        """Advance one substep of length ``dt``; returns the number of clamped particles."""
        p, s, g, geo, backend = self.particles, self.state, self.grid, self.geometry, self.backend
        try:
            bins = ops.bin_particles(s.x, self.grid_id, geo, backend)
        except RuntimeError as exc:
            raise SimulationBlowUp(f"t={s.time:.6g}s: {exc}") from None
        fields = self.field_geometry
        if self.fragments and not self._damage_started:  # nothing to split before any fracture
            # (a damaged particle has its fracture flag set: damage needs α above the threshold)
            self._damage_started = bool(s.fractured.any())
        partition = self.fragments and self._damage_started
        ops.p2g(bins, s.x, s.v, s.C, self.stress, p.mass, p.rest_volume, self.grid_id, fields, dt, g, backend,
                damaged=self.damaged() if partition else None)
        field_bins, fragments = bins, None
        if partition:
            field_bins, fragments = self._partition(bins, dt)
        ops.grid_update(field_bins, fields, dt, self.gravity, self.mass_eps, g, backend)
        if self.use_contact or fragments is not None:
            ops.collision(field_bins, fields, self.contact.impulse_scale, self.contact.friction, self.mass_eps,
                          self.max_contact_gap, g, backend)
        self.external_impulse.step(field_bins.touched, g, dt, lambda: ops.boundaries(
            field_bins, fields, self.wall_condition, self.ground_height, self.ground_friction, self.mass_eps, g,
            backend))
        dissipated = torch.empty(len(p), device=self.device) if self._dissipates else None
        x, v, C, F_E, material_state, stress, fractured, stats = ops.g2p(
            s.x, s.F_E, s.material_state, s.fractured, self.grid_id, p.material_id, self.material_table, g, geo, dt,
            backend, fragments=fragments, dissipated=dissipated)
        if fragments is not None:  # fields B are zero again for the next substep
            ops.fragment_clear(field_bins.touched[len(bins.touched):], fields, g, backend)
        self._split_particle = fragments.split_particle if fragments is not None else None
        self._check(stats, v, dt)
        rigid_speed = 0.0
        if len(self.rigid):
            rigid_speed, ground_impulse = self.rigid.project(x, v, C, F_E, stress, self.input_index, dt)
            self.external_impulse.add(ground_impulse)
        if dissipated is not None:
            if self._dissipated_pending is None:
                self._dissipated_pending = dissipated
            else:
                self._dissipated_pending.add_(dissipated)
        for cls, _ in self._models:
            cls.after_substep(SubstepView(state_old=s.material_state, state=material_state, F_E=F_E, C=C, dt=dt,
                                          mine=self._particles_of(cls), cache=self._model_cache.setdefault(cls, {}),
                                          backend=backend))
        self.state = SimState(x=x, v=v, C=C, F_E=F_E, material_state=material_state, fractured=fractured,
                              time=s.time + dt, step=s.step + 1)
        self.stress = stress
        self.last_bins = bins
        self.max_speed = max(stats.max_speed, rigid_speed)
        if self.reorder_every and self.state.step % self.reorder_every == 0:
            self.reorder()
        elif self.state.step % DISSIPATION_FLUSH_STEPS == 0:
            self._flush_dissipated()
        return stats.clamped

    def _partition(self, bins: ParticleBins, dt: float) -> tuple[ParticleBins, FragmentFields | None]:
        """Damage-gradient partitioning of the object grids (csrc/common/mpm_fragments.h): the
        reference of every node, fields A and B at the split nodes. Returns the bins the field
        passes use (touched: plus the fields B of split blocks; contact: plus the split blocks) and
        what G2P needs, or (bins, None) where no node is split."""
        p, s, g, geo = self.particles, self.state, self.grid, self.geometry
        directions = self.table.split_directions(s.material_state, p.material_id)
        damage_gradient = ops.fragment_reference(bins, s.x, self.grid_id, geo, self.mass_eps, self.split_gradient, g,
                                                 self.backend, split_direction=directions,
                                                 direction_scale=SPLIT_DIRECTION_CELLS / geo.dx)
        split_particle, split_keys, side_mask = ops.fragment_partition(
            bins, s.x, s.v, s.C, self.stress, p.mass, p.rest_volume, self.grid_id, geo, dt, damage_gradient,
            self.split_gradient, g, self.backend)
        if len(split_keys) == 0:
            return bins, None
        touched, contact_blocks = ops.fragment_field_blocks(bins, split_keys, geo, self.backend)
        field_bins = dataclasses.replace(bins, touched=touched, contact_blocks=contact_blocks)
        return field_bins, FragmentFields(damage_gradient, g.reference, split_particle.contiguous(),
                                          self.split_gradient, side_mask.contiguous())

    @property
    def dissipated_energy(self) -> torch.Tensor:
        """(n_objects,) float64: the energy the material updates have dissipated so far, per object."""
        self._flush_dissipated()
        return self._dissipated_total

    def _flush_dissipated(self) -> None:
        """Adds the pending dissipated energy densities (per particle, per unit rest volume, summed
        over the substeps since the last flush) times the rest volumes to the per-object totals."""
        pending, self._dissipated_pending = self._dissipated_pending, None
        if pending is None:
            return
        taken = torch.nonzero(pending).flatten()
        if len(taken) == 0:
            return
        p = self.particles
        energy = pending[taken].double() * p.rest_volume[taken].double()
        self._dissipated_total.index_add_(0, p.obj_id[taken].long(), energy)

    def _particles_of(self, cls: type) -> torch.Tensor:
        """(N) bool, current order: the particles whose material's model is ``cls``."""
        if cls not in self._model_particles:
            rows = next(rows for model, rows in self._models if model is cls)
            ids = torch.tensor(rows, dtype=self.particles.material_id.dtype, device=self.device)
            self._model_particles[cls] = torch.isin(self.particles.material_id, ids)
        return self._model_particles[cls]

    def reorder(self) -> None:
        """Sort the particles by object, grid block and cell again (faster transfers).

        Only the storage order changes: every per-particle array moves alike, so the physics is
        the same up to the order in which P2G sums a node's contributions.
        """
        self._apply_order(spatial_order(self.state.x, self.particles.obj_id, self.domain))

    def _apply_order(self, order: torch.Tensor) -> None:
        """Move every per-particle array so that new row i is old row order[i]."""
        self._flush_dissipated()
        self.particles = self.particles.take(order)
        self.state = self.state.take(order)
        self.grid_id = torch.index_select(self.grid_id, 0, order)
        self.stress = torch.index_select(self.stress, 0, order)
        self._model_particles = {}
        self._model_cache = {}
        self.input_index = torch.index_select(self.input_index, 0, order)
        self.rigid.reordered()

    def state_in_input_order(self) -> SimState:
        """The state with rows in the order of the ParticleSet given to the constructor."""
        return self.state.take(inverse_permutation(self.input_index))

    def frame_fields_in_input_order(self) -> dict[str, torch.Tensor]:
        """The material state fields every frame holds (``MaterialTable.frame_fields``, e.g. the
        brittle ``damage``), (N,) float32 each, in the constructor's order."""
        return self.table.frame_fields(self.state_in_input_order().material_state, self.input_particles.material_id)

    def fragment_ids(self) -> torch.Tensor:
        """(N,) int64 fragment label of every particle, rows in the constructor's order (connected
        pieces of each object, :mod:`fracture_gs.mpm.fragments`; particles whose state field 0 has
        reached their material's piece threshold, e.g. brittle particles with complete damage, are pieces
        of their own); cached per substep."""
        if self._fragment_cache is None or self._fragment_cache[0] != self.state.step:
            broken = None
            if bool(torch.isfinite(self.piece_threshold).any()):
                threshold = torch.index_select(self.piece_threshold, 0, self.input_particles.material_id)
                broken = self.state_in_input_order().alpha >= threshold
            labels = fragment_ids(self.state_in_input_order().x, self.input_particles.obj_id, self.fragment_radius,
                                  backend=self.backend, broken=broken)
            self._fragment_cache = (self.state.step, labels)
        return self._fragment_cache[1]

    def _check(self, stats: G2PStats, v: torch.Tensor, dt: float) -> None:
        """Refuse a substep whose result is non-finite or moves a particle more than one cell
        (the state is not committed, so the frames written so far stay valid)."""
        where = f"t={self.state.time + dt:.6g}s (step {self.state.step + 1})"
        if stats.first_nonfinite >= 0:
            particle = int(self.input_index[stats.first_nonfinite])  # as numbered in the input
            raise SimulationBlowUp(f"{where}: non-finite position, velocity or deformation gradient at particle "
                                   f"{particle}; try a smaller cfl or a finer grid")
        if stats.max_speed * dt > self.geometry.dx:
            # CFL keeps |v| dt to cfl * dx at the step's start: a particle that now crosses more than
            # a cell in one substep was accelerated beyond anything the time step resolves.
            speed = torch.linalg.vector_norm(v, dim=1)
            fastest = int(torch.argmax(torch.where(torch.isfinite(speed), speed, torch.zeros_like(speed))))
            particle = int(self.input_index[fastest])
            cells = stats.max_speed * dt / self.geometry.dx
            raise SimulationBlowUp(f"{where}: particle {particle} would move {cells:.3g} cells in one substep "
                                   f"(speed {stats.max_speed:.3g}); try a smaller cfl or a finer grid")

    def advance(self, duration: float) -> StepStats:
        """Run substeps with the adaptive CFL step until ``duration`` seconds have passed."""
        end = self.state.time + duration
        steps, dt_min, clamped = 0, math.inf, 0
        while end - self.state.time > 1e-12 * max(1.0, abs(end)):
            stable = self.stable_dt()
            clamped += self.step(min(stable, end - self.state.time))
            steps += 1
            dt_min = min(dt_min, stable)  # the CFL limit, not the frame's shortened last substep
        self.state.time = end  # remove round-off so frames land on exact times
        return StepStats(steps=steps, dt_min=dt_min if steps else 0.0, clamped=clamped)

    # ------------------------------------------------------------------ diagnostics
    def diagnostics(self) -> dict:
        """Momentum and energies (float64 sums), total and per object, the fractured count, the
        fragment count and the external impulse J since step 0 (gravity and boundaries;
        :mod:`fracture_gs.mpm.impulse`): p(t) − p(0) = J(t) up to round-off."""
        p, s = self.particles, self.state
        mass = p.mass.double()
        v = s.v.double()
        kinetic = 0.5 * mass * (v * v).sum(1)
        psi = elastic_energy(s.F_E, self.material_table, p.material_id, backend=self.backend,
                             state=s.material_state).double()
        elastic = psi * p.rest_volume.double()
        gravity = torch.tensor(self.gravity, device=self.device, dtype=torch.float64)
        reference_height = torch.tensor(self._potential_origin(), device=self.device, dtype=torch.float64)
        gravitational = -mass * ((s.x.double() - reference_height) @ gravity)
        momentum = mass[:, None] * v
        obj = p.obj_id.long()

        def per_object(values: torch.Tensor) -> torch.Tensor:
            shape = (self.n_objects,) + tuple(values.shape[1:])
            return torch.zeros(shape, dtype=values.dtype, device=values.device).index_add_(0, obj, values)

        mom_obj, kin_obj, ela_obj, grav_obj = (per_object(t).cpu().numpy()
                                               for t in (momentum, kinetic, elastic, gravitational))
        dissipated_obj = self.dissipated_energy.cpu().numpy()
        return {
            "momentum": momentum.sum(0).cpu().numpy(),
            "kinetic": float(kinetic.sum()),
            "elastic": float(elastic.sum()),
            "gravitational": float(gravitational.sum()),
            "total_energy": float(kinetic.sum() + elastic.sum() + gravitational.sum()),
            "dissipated_energy": float(dissipated_obj.sum()),
            "fractured": int(s.fractured.sum()),
            "fragments": count_fragments(self.fragment_ids(), self.input_particles.obj_id),
            "external_impulse": self.external_impulse.state(),
            "per_object": [{"name": self.object_names[k], "momentum": mom_obj[k], "kinetic": float(kin_obj[k]),
                            "elastic": float(ela_obj[k]), "gravitational": float(grav_obj[k]),
                            "dissipated_energy": float(dissipated_obj[k])}
                           for k in range(self.n_objects)],
        }

    def _potential_origin(self) -> list[float]:
        """Zero of the gravitational potential: the ground if there is one, else the domain floor."""
        origin = list(self.domain.lower)
        if self.ground_height is not None:
            origin[2] = self.ground_height
        return origin

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Everything needed to continue bit-identically (numpy arrays in the solver's current
        particle order, that order as ``input_index``, the clock, and the largest speed that G2P
        reported, which sets the next CFL step: recomputing it from ``v`` with torch can differ
        in the last bit and change every step after a resume)."""
        arrays = {key: getattr(self.state, key) for key in STATE_KEYS if key != "stress"}
        arrays["stress"] = self.stress
        arrays["input_index"] = self.input_index
        out = {key: value.cpu().numpy() for key, value in arrays.items()}
        out["time"] = np.float64(self.state.time)
        out["step"] = np.int64(self.state.step)
        out["max_speed"] = np.float64(self.max_speed)
        out["external_impulse"] = np.asarray(self.external_impulse.state(), dtype=np.float64)
        out["dissipated_energy"] = self.dissipated_energy.cpu().numpy()
        out.update(self.rigid.state_dict())
        return out

    def load_state_dict(self, data: dict) -> None:
        """Restore a state written by :meth:`state_dict`."""
        n = len(self.particles)
        tensors = {}
        for key in STATE_KEYS:
            if key not in data:
                raise KeyError(f"checkpoint has no '{key}'")
            value = torch.as_tensor(np.asarray(data[key]), device=self.device)
            if value.shape[0] != n:
                raise ValueError(f"checkpoint '{key}' has {value.shape[0]} particles, the scene has {n}")
            tensors[key] = value.contiguous()
        # The particle order the state was saved in (checkpoints without it: the input order).
        order = torch.arange(n, device=self.device)
        if "input_index" in data:
            order = torch.as_tensor(np.asarray(data["input_index"]), device=self.device).long()
            if order.shape != (n,) or not torch.equal(torch.sort(order).values, torch.arange(n, device=self.device)):
                raise ValueError("checkpoint 'input_index' is not a permutation of the scene's particles")
        self.particles = self.input_particles.take(order)
        self._model_particles = {}
        self._model_cache = {}
        self.grid_id = self._grid_ids(self.particles)
        self.input_index = order
        self.rigid.reordered()
        if len(self.rigid):
            if "rigid_centre" not in data or "rigid_rotation" not in data:
                raise KeyError("checkpoint has no 'rigid_centre' / 'rigid_rotation' (the scene has rigid objects)")
            self.rigid.load_state_dict(np.asarray(data["rigid_centre"]), np.asarray(data["rigid_rotation"]))
        self.stress = tensors.pop("stress").float()
        material_state = tensors["material_state"].float()
        width = self.table.state_width
        if material_state.shape != (n, width):
            raise ValueError(f"checkpoint 'material_state' has shape {tuple(material_state.shape)}, the scene's "
                             f"materials have ({n}, {width})")
        self.state = SimState(x=tensors["x"].float(), v=tensors["v"].float(), C=tensors["C"].float(),
                              F_E=tensors["F_E"].float(), material_state=material_state.contiguous(),
                              fractured=tensors["fractured"].bool(), time=float(data["time"]),
                              step=int(data["step"]))
        self._damage_started = False
        self._split_particle = None
        # Checkpoints from before max_speed was stored: recomputed (may differ in the last bit).
        self.max_speed = (float(data["max_speed"]) if "max_speed" in data
                          else float(self.state.v.norm(dim=1).max()) if n else 0.0)
        # The impulse gravity and the boundaries gave so far (zero for checkpoints without it).
        self.external_impulse.load([float(v) for v in np.asarray(data["external_impulse"]).reshape(3)]
                                   if "external_impulse" in data else None)
        self._fragment_cache = None  # labels belong to the state they were computed from
        if "dissipated_energy" not in data:
            raise KeyError("checkpoint has no 'dissipated_energy'")
        dissipated = np.asarray(data["dissipated_energy"], dtype=np.float64)
        if dissipated.shape != (self.n_objects,):
            raise ValueError(f"checkpoint 'dissipated_energy' has shape {dissipated.shape}, the scene has "
                             f"{self.n_objects} objects")
        self._dissipated_total = torch.as_tensor(dissipated, dtype=torch.float64, device=self.device)
        self._dissipated_pending = None
