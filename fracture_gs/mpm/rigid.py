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

The grid's boundary pass stops only the nodes under the few particles that touch the ground or a
wall, which a rigid body shares out over all its mass: alone it would let a table sink slowly into
the floor. So the ground and the planes particles are clamped to (the walls' inner faces) are also
constraints on the body's motion: every particle within a cell of a plane n·x = h must end the
substep on its side, n·(x_p + Δt (V + ω × r_p)) ≥ h (speculative contact: no impulse before the
gap closes, none that pulls), or climb back by a fifth of its depth per substep where it already
lies beyond. The smallest change of (V, ω) in the body's mass metric that meets all of them is a
least-distance problem, solved exactly through non-negative least squares; Coulomb friction then
takes up to μ times each plane's normal impulse from the body's sliding speed along it (sticky
walls: all of it). The impulse counts in the solver's external impulse J.

The body's material keys set its mass (density) only: its wave speed does not limit the time step
(``CollisionMPM.stable_dt``). Centre and rotation are part of the solver's checkpoint, so a
resumed run is bit-identical.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from scipy.optimize import nnls

from fracture_gs.mpm.ordering import inverse_permutation

CONTACT_MARGIN_CELLS = 1.0  # particles this close to a plane are contact candidates
RECOVERY = 0.2              # share of a penetration undone per substep


@dataclass(frozen=True)
class ContactPlane:
    """A plane a rigid body stays on one side of: n · x ≥ offset, with Coulomb friction μ (inf: no
    sliding at all)."""

    normal: tuple[float, float, float]
    offset: float
    friction: float = 0.0


def axial_of(matrix: np.ndarray) -> np.ndarray:
    """The vector a with a_k = ε_kij M_ji: twice the axial vector of the skew part of a (3, 3) matrix
    (for M = [ω]× it is 2 ω)."""
    return np.array([matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]])


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
    moments: torch.Tensor         # (4, n) float64: the masses m and the rows of (m r₀)ᵀ
    total_mass: float
    radius: float                 # the largest |r₀|
    half_extent: np.ndarray       # (3,), the largest |r₀| per body axis: a box that holds the body
    inertia: np.ndarray           # (3, 3), rest inertia about the mass centre incl. the affine share
    centre: np.ndarray            # (3,) float64
    rotation: np.ndarray          # (3, 3) float64


class RigidBodies:
    """The scene's rigid objects and the projection that keeps each one rigid after G2P."""

    def __init__(self, objects: Sequence[int], x: torch.Tensor, mass: torch.Tensor, obj_id: torch.Tensor,
                 dx: float, planes: Sequence[ContactPlane] = ()) -> None:
        """``x``, ``mass`` and ``obj_id``: the solver's input particles (constructor order); the
        planes the bodies stay on one side of (the ground, the walls' inner faces)."""
        self.affine = 0.25 * dx * dx   # D = Δx²/4 of the quadratic kernel's APIC transfer
        self.dx = float(dx)
        self.planes = list(planes)
        self._normals = [np.asarray(plane.normal, dtype=np.float64) for plane in self.planes]
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
            moments = torch.cat([m[None, :], (m[:, None] * offset).T]).contiguous()
            self.bodies.append(RigidBody(index, rows, offset, moments, float(total),
                                         float(squared.max().sqrt()), offset.abs().amax(0).cpu().numpy(),
                                         inertia.cpu().numpy(), centre.cpu().numpy(), np.eye(3)))
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
            where = inverse_permutation(input_index)
            self._current_rows = [torch.index_select(where, 0, body.input_rows) for body in self.bodies]
        return self._current_rows

    def project(self, x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, F_E: torch.Tensor, stress: torch.Tensor,
                input_index: torch.Tensor, dt: float) -> tuple[float, torch.Tensor]:
        """Replace the rigid particles' G2P results (in place, current order) by their body's rigid
        motion. Returns a bound on the largest rigid particle speed (|V| + |ω| max|r₀|; 0 without
        bodies) and the (3,) float64 impulse the contact planes gave the bodies."""
        fastest = 0.0
        plane_impulse = np.zeros(3)
        for body, rows in zip(self.bodies, self.current_rows(input_index)):
            # one product gives Σ m v, Σ m C and Σ m r₀ vᵀ: the body's momenta
            gathered = torch.cat([torch.index_select(v, 0, rows), torch.index_select(C, 0, rows).reshape(-1, 9)], 1)
            sums = (body.moments @ gathered.double()).cpu().numpy()
            start = body.rotation
            moment = start @ sums[1:, :3]                       # Σ m r vᵀ with r at the step's start
            # Σ m r × v = -axial(Σ m r vᵀ), plus the affine share D axial(Σ m C)
            angular = self.affine * axial_of(sums[0, 3:].reshape(3, 3)) - axial_of(moment)
            linear = sums[0, :3] / body.total_mass
            inertia = start @ body.inertia @ start.T
            spin = np.linalg.solve(inertia, angular)
            if self.planes:
                constrained, spin = self._plane_contact(body, linear, spin, inertia, dt)
                plane_impulse += body.total_mass * (constrained - linear)
                angular = inertia @ spin
                linear = constrained
            body.centre = body.centre + dt * linear
            body.rotation = orthonormal(rotation_exp(dt * spin) @ start)
            spin = np.linalg.solve(body.rotation @ body.inertia @ body.rotation.T, angular)
            # x = X + R r₀ and v = V + ω × (R r₀) in one product with [Rᵀ | Rᵀ [ω]×ᵀ]
            turn = np.concatenate([body.rotation.T, body.rotation.T @ skew(spin).T], axis=1)
            base = torch.as_tensor(np.concatenate([body.centre, linear]), device=x.device)
            motion = torch.addmm(base, body.offset, torch.as_tensor(turn, device=x.device)).to(x.dtype)
            x.index_copy_(0, rows, motion[:, :3].contiguous())
            v.index_copy_(0, rows, motion[:, 3:].contiguous())
            constant = torch.as_tensor(np.stack([skew(spin), body.rotation]), dtype=C.dtype, device=x.device)
            C.index_copy_(0, rows, constant[0].expand(len(rows), 3, 3).contiguous())
            F_E.index_copy_(0, rows, constant[1].expand(len(rows), 3, 3).contiguous())
            stress.index_fill_(0, rows, 0.0)
            fastest = max(fastest, float(np.linalg.norm(linear) + np.linalg.norm(spin) * body.radius))
        return fastest, torch.as_tensor(plane_impulse, device=x.device)

    def _plane_contact(self, body: RigidBody, linear: np.ndarray, spin: np.ndarray, inertia: np.ndarray,
                       dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The body's velocity and spin after the plane constraints (module docstring), for the body
        as it stands at the substep's start."""
        rows, bounds, owners = [], [], []
        margin = CONTACT_MARGIN_CELLS * self.dx
        for k, (plane, normal) in enumerate(zip(self.planes, self._normals)):
            centre_distance = float(normal @ body.centre) - plane.offset
            # the body's box reaches no closer to the plane than this: most planes need no particle
            if centre_distance - float(np.abs(body.rotation.T @ normal) @ body.half_extent) >= margin:
                continue
            along = torch.as_tensor(body.rotation.T @ normal, device=body.offset.device)
            distance = body.offset @ along + centre_distance
            near = torch.nonzero(distance < margin).flatten()
            if len(near) == 0:
                continue
            r = body.offset.index_select(0, near).cpu().numpy() @ body.rotation.T
            gap = distance.index_select(0, near).cpu().numpy()
            rows.append(np.concatenate([np.broadcast_to(normal, r.shape), r @ skew(normal)], axis=1))  # r × n
            bounds.append(np.where(gap >= 0.0, -gap / dt, -RECOVERY * gap / dt))
            owners.append(np.full(len(r), k))
        if not rows:
            return linear, spin
        jacobian, bound, owner = np.concatenate(rows), np.concatenate(bounds), np.concatenate(owners)
        free = np.concatenate([linear, spin])
        excess = bound - jacobian @ free
        if float(excess.max()) <= 0.0:
            return linear, spin
        # least-distance problem min |y| s.t. G y >= h with y = M^(1/2) (u - u_free), G = J M^(-1/2),
        # solved through non-negative least squares (Lawson and Hanson, ch. 23); the constraints'
        # impulses are λ = z / (1 - h·z)
        mass = body.total_mass
        values, vectors = np.linalg.eigh(inertia)
        root_inverse = np.zeros((6, 6))
        root_inverse[:3, :3] = np.eye(3) / math.sqrt(mass)
        root_inverse[3:, 3:] = (vectors / np.sqrt(values)) @ vectors.T
        system = np.vstack([(jacobian @ root_inverse).T, excess[None, :]])
        target = np.zeros(7)
        target[6] = 1.0
        weights, _ = nnls(system, target)
        residual = system @ weights - target
        if abs(residual[6]) < 1e-12:    # infeasible: the body is wedged between planes
            return linear, spin
        velocity = free + root_inverse @ (-residual[:6] / residual[6])
        impulse = weights / -residual[6]
        for k, (plane, normal) in enumerate(zip(self.planes, self._normals)):
            normal_impulse = float(impulse[owner == k].sum())
            if normal_impulse <= 0.0:
                continue
            sliding = velocity[:3] - (velocity[:3] @ normal) * normal
            speed = float(np.linalg.norm(sliding))
            if speed > 0.0:
                velocity[:3] -= sliding * min(1.0, plane.friction * normal_impulse / mass / speed)
        return velocity[:3], velocity[3:]

    def state_dict(self) -> dict[str, np.ndarray]:
        """Centres (B, 3) and rotations (B, 3, 3), float64 (nothing without bodies)."""
        if not self.bodies:
            return {}
        return {"rigid_centre": np.stack([body.centre for body in self.bodies]),
                "rigid_rotation": np.stack([body.rotation for body in self.bodies])}

    def load_state_dict(self, centre: np.ndarray, rotation: np.ndarray) -> None:
        """Restore what :meth:`state_dict` wrote."""
        if centre.shape != (len(self.bodies), 3) or rotation.shape != (len(self.bodies), 3, 3):
            raise ValueError(f"checkpoint rigid bodies have shapes {tuple(centre.shape)} / {tuple(rotation.shape)}, "
                             f"the scene has {len(self.bodies)} rigid objects")
        for k, body in enumerate(self.bodies):
            body.centre = np.array(centre[k], dtype=np.float64)
            body.rotation = np.array(rotation[k], dtype=np.float64)
