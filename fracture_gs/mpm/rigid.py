"""Rigid bodies inside the MPM step: objects marked ``rigid: true`` (docs/formulas.md §9b).

A stiff object that never breaks (a table, a floor slab) would set the explicit step of the whole
scene through its wave speed, and softened enough to be affordable it bends. Here such an object
is the limit of infinite stiffness instead: its particles take part in P2G and G2P like any
other (so contact, gravity and the boundaries act on it through the grid), and after G2P their
velocities are projected onto a rigid motion of the body:

* linear momentum P = Σ m v and angular momentum about the mass centre
  L = Σ m r × v + (Δx²/4) Σ m axial(C), the APIC affine velocity's share with the quadratic
  kernel's D = Δx²/4 I, are kept exactly;
* the body's velocity V = P / M and spin ω = I⁻¹ L, with I = Σ m (|r|² 1 − r rᵀ) + 2 (Δx²/4) M 1
  (the affine share counted as for L), advance its centre X and rotation R one step
  (X += Δt V, R ← exp(Δt [ω]×) R, in float64);
* every particle is put back at X + R r₀ (r₀ its rest offset from the rest mass centre), with
  v = V + ω' × r, C = [ω']× (ω' = I'⁻¹ L for the new orientation, so L is also kept after the
  move), F_E = R and no stress.

The projection is the orthogonal one in the APIC kinetic energy's inner product, so it never adds
kinetic energy.

The grid's boundary pass stops only the nodes under the few particles that touch the ground, which
a rigid body shares out over all its mass: alone it would let a table sink slowly into the floor.
So the ground is also a constraint on the body's motion: every particle within a cell of the ground
must end the substep above it, z_p + Δt (V + ω × r_p)_z ≥ h (speculative contact: no impulse
before the gap closes, none that pulls), or climb back by a fifth of its depth per substep where it
already lies below. The smallest change of (V, ω) in the body's mass metric that meets all of
them is a least-distance problem, solved exactly through non-negative least squares; Coulomb friction then takes up to μ times the normal impulse from
the body's sliding speed. The impulse counts in the solver's external impulse J. The body's material keys set its mass (density) only: its wave speed does not
limit the time step (``CollisionMPM.stable_dt``). Centre and rotation are part of the solver's
checkpoint, so a resumed run is bit-identical.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from scipy.optimize import nnls

GROUND_MARGIN_CELLS = 1.0   # particles this close to the ground are contact candidates
GROUND_RECOVERY = 0.2       # share of a penetration undone per substep


def axial(matrices: torch.Tensor) -> torch.Tensor:
    """(n, 3) vectors a with a_k = ε_kij M_ji: twice the axial vector of the skew part of each (n, 3, 3)
    matrix (for M = [ω]× it is 2 ω)."""
    return torch.stack((matrices[:, 2, 1] - matrices[:, 1, 2], matrices[:, 0, 2] - matrices[:, 2, 0],
                        matrices[:, 1, 0] - matrices[:, 0, 1]), dim=1)


def skew(vector: np.ndarray) -> np.ndarray:
    """(3, 3) matrix [w]× with [w]× r = w × r."""
    return np.array([[0.0, -vector[2], vector[1]], [vector[2], 0.0, -vector[0]], [-vector[1], vector[0], 0.0]])


def rotation_exp(rotation_vector: np.ndarray) -> np.ndarray:
    """(3, 3) rotation exp([θ]×) of a rotation vector θ (Rodrigues' formula)."""
    angle = float(np.linalg.norm(rotation_vector))
    k = skew(rotation_vector)
    if angle < 1e-8:   # second-order series: exact to round-off at these angles
        return np.eye(3) + k + 0.5 * (k @ k)
    return np.eye(3) + (math.sin(angle) / angle) * k + ((1.0 - math.cos(angle)) / angle ** 2) * (k @ k)


def orthonormal(matrix: np.ndarray) -> np.ndarray:
    """The rotation nearest ``matrix`` (polar factor), removing the drift of repeated products."""
    u, _, vh = np.linalg.svd(matrix)
    return u @ vh


@dataclass
class RigidBody:
    """One rigid object: its particles (rows in the constructor's order), their rest offsets from the
    rest mass centre, its mass and rest inertia, and its current centre and rotation (float64)."""

    object_index: int
    input_rows: torch.Tensor      # (n,) int64, rows of the solver's input ParticleSet
    offset: torch.Tensor          # (n, 3) float64, r₀ in the body frame
    mass: torch.Tensor            # (n,) float64
    total_mass: float
    inertia: np.ndarray           # (3, 3), rest inertia about the mass centre incl. the affine share
    centre: np.ndarray            # (3,) float64
    rotation: np.ndarray          # (3, 3) float64


class RigidBodies:
    """The scene's rigid objects and the projection that keeps each one rigid after G2P."""

    def __init__(self, objects: Sequence[int], x: torch.Tensor, mass: torch.Tensor, obj_id: torch.Tensor,
                 dx: float, ground_height: float | None = None, ground_friction: float = 0.0) -> None:
        """``x``, ``mass`` and ``obj_id``: the solver's input particles (constructor order); the
        ground plane z = ``ground_height`` (None: none) with its friction coefficient."""
        self.affine = 0.25 * dx * dx   # D = Δx²/4 of the quadratic kernel's APIC transfer
        self.dx = float(dx)
        self.ground_height = ground_height
        self.ground_friction = float(ground_friction)
        self.bodies: list[RigidBody] = []
        eye = torch.eye(3, dtype=torch.float64, device=x.device)
        for index in sorted(set(int(i) for i in objects)):
            rows = torch.nonzero(obj_id == index).flatten()
            if len(rows) == 0:
                continue
            m = mass[rows].double()
            positions = x[rows].double()
            total = m.sum()
            centre = (m[:, None] * positions).sum(0) / total
            offset = positions - centre
            squared = (offset * offset).sum(1)
            inertia = (m * squared).sum() * eye - (m[:, None, None] * offset[:, :, None] * offset[:, None, :]).sum(0)
            inertia = inertia + 2.0 * self.affine * total * eye
            self.bodies.append(RigidBody(index, rows, offset, m, float(total), inertia.cpu().numpy(),
                                         centre.cpu().numpy(), np.eye(3)))
        self._current_rows: list[torch.Tensor] | None = None

    def __len__(self) -> int:
        return len(self.bodies)

    @property
    def objects(self) -> list[int]:
        """Object indices of the rigid bodies."""
        return [body.object_index for body in self.bodies]

    def reordered(self) -> None:
        """The solver's particle order changed: current rows are looked up again."""
        self._current_rows = None

    def current_rows(self, input_index: torch.Tensor) -> list[torch.Tensor]:
        """Per body, the current rows of its particles (``input_index[i]``: input row of current row i)."""
        if self._current_rows is None:
            where = torch.empty_like(input_index)
            where[input_index] = torch.arange(len(input_index), device=input_index.device)
            self._current_rows = [torch.index_select(where, 0, body.input_rows) for body in self.bodies]
        return self._current_rows

    def project(self, x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, F_E: torch.Tensor, stress: torch.Tensor,
                input_index: torch.Tensor, dt: float) -> tuple[float, torch.Tensor]:
        """Replace the rigid particles' G2P results (in place, current order) by their body's rigid
        motion. Returns the largest rigid particle speed (0 without bodies) and the (3,) float64
        impulse the ground gave the bodies."""
        fastest = 0.0
        ground_impulse = np.zeros(3)
        for body, rows in zip(self.bodies, self.current_rows(input_index)):
            velocity = torch.index_select(v, 0, rows).double()
            affine = torch.index_select(C, 0, rows).double()
            m = body.mass[:, None]
            rotation = torch.as_tensor(body.rotation, device=x.device)
            arm = body.offset @ rotation.T                      # r at the step's start
            sums = torch.cat([(m * velocity).sum(0), (m * torch.cross(arm, velocity, dim=1)).sum(0)
                              + self.affine * (m * axial(affine)).sum(0)]).cpu().numpy()
            linear, angular = sums[:3] / body.total_mass, sums[3:]
            inertia = body.rotation @ body.inertia @ body.rotation.T
            spin = np.linalg.solve(inertia, angular)
            if self.ground_height is not None:
                constrained, spin = self._ground_contact(body, arm, linear, spin, inertia, dt)
                ground_impulse += body.total_mass * (constrained - linear)
                angular = inertia @ spin
                linear = constrained
            body.centre = body.centre + dt * linear
            body.rotation = orthonormal(rotation_exp(dt * spin) @ body.rotation)
            spin = np.linalg.solve(body.rotation @ body.inertia @ body.rotation.T, angular)
            rotation = torch.as_tensor(body.rotation, device=x.device)
            arm = body.offset @ rotation.T
            spin_t = torch.as_tensor(spin, device=x.device)
            new_velocity = torch.as_tensor(linear, device=x.device) + torch.cross(spin_t.expand_as(arm), arm, dim=1)
            x.index_copy_(0, rows, (torch.as_tensor(body.centre, device=x.device) + arm).to(x.dtype))
            v.index_copy_(0, rows, new_velocity.to(v.dtype))
            C.index_copy_(0, rows, torch.as_tensor(skew(spin), dtype=C.dtype, device=x.device)
                          .expand(len(rows), 3, 3).contiguous())
            F_E.index_copy_(0, rows, rotation.to(F_E.dtype).expand(len(rows), 3, 3).contiguous())
            stress.index_fill_(0, rows, 0.0)
            fastest = max(fastest, float(torch.linalg.vector_norm(new_velocity, dim=1).max()))
        return fastest, torch.as_tensor(ground_impulse, device=x.device)

    def _ground_contact(self, body: RigidBody, arm: torch.Tensor, linear: np.ndarray, spin: np.ndarray,
                        inertia: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The body's velocity and spin after the ground constraint (module docstring); ``arm``: the
        particles' offsets from the centre at the substep's start."""
        assert self.ground_height is not None
        height = float(body.centre[2]) + arm[:, 2]
        near = torch.nonzero(height < self.ground_height + GROUND_MARGIN_CELLS * self.dx).flatten()
        if len(near) == 0:
            return linear, spin
        r = arm.index_select(0, near).cpu().numpy()
        gap = height.index_select(0, near).cpu().numpy() - self.ground_height
        # constraint rows J u >= b with u = (V, ω), n = z: J = (n, r × n), b = -gap/dt or recovery
        rows = np.zeros((len(r), 6))
        rows[:, 2] = 1.0
        rows[:, 3], rows[:, 4] = r[:, 1], -r[:, 0]
        bound = np.where(gap >= 0.0, -gap / dt, -GROUND_RECOVERY * gap / dt)
        free = np.concatenate([linear, spin])
        excess = bound - rows @ free
        if float(excess.max()) <= 0.0:
            return linear, spin
        # least-distance problem min |y| s.t. G y >= h with y = M^(1/2) (u - u_free), G = J M^(-1/2),
        # solved through non-negative least squares (Lawson and Hanson, ch. 23)
        mass = body.total_mass
        values, vectors = np.linalg.eigh(inertia)
        root_inverse = np.zeros((6, 6))
        root_inverse[:3, :3] = np.eye(3) / math.sqrt(mass)
        root_inverse[3:, 3:] = (vectors / np.sqrt(values)) @ vectors.T
        metric_rows = rows @ root_inverse
        system = np.vstack([metric_rows.T, excess[None, :]])
        target = np.zeros(7)
        target[6] = 1.0
        weights, _ = nnls(system, target)
        residual = system @ weights - target
        if abs(residual[6]) < 1e-12:    # infeasible: cannot happen for a plane below the body
            return linear, spin
        velocity = free + root_inverse @ (-residual[:6] / residual[6])
        normal = mass * float(velocity[2] - free[2])   # every constraint pushes along +z
        sliding = velocity[:2]
        speed = float(np.hypot(*sliding))
        if speed > 0.0 and normal > 0.0:
            velocity[:2] *= max(0.0, 1.0 - self.ground_friction * normal / mass / speed)
        return velocity[:3], velocity[3:]

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Centres (B, 3) and rotations (B, 3, 3), float64."""
        if not self.bodies:
            return {}
        return {"rigid_centre": torch.as_tensor(np.stack([body.centre for body in self.bodies])),
                "rigid_rotation": torch.as_tensor(np.stack([body.rotation for body in self.bodies]))}

    def load_state_dict(self, centre: torch.Tensor, rotation: torch.Tensor) -> None:
        """Restore what :meth:`state_dict` wrote."""
        if centre.shape != (len(self.bodies), 3) or rotation.shape != (len(self.bodies), 3, 3):
            raise ValueError(f"checkpoint rigid bodies have shapes {tuple(centre.shape)} / {tuple(rotation.shape)}, "
                             f"the scene has {len(self.bodies)} rigid objects")
        for k, body in enumerate(self.bodies):
            body.centre = centre[k].double().cpu().numpy().copy()
            body.rotation = rotation[k].double().cpu().numpy().copy()
