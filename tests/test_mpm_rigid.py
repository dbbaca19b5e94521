"""Rigid objects (fracture_gs.mpm.rigid): the projection keeps momentum and angular momentum and never
adds energy; a struck rigid bar moves as one piece at once, bounces off without sticking or passing
through; its wave speed sets no time step; resumed runs are bit-identical; the scene key is checked."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fracture_gs.config.scene import SceneError, parse_scene
from fracture_gs.materials import ElasticMaterial
from fracture_gs.metrics.shape import rigid_fit_residual
from fracture_gs.mpm.rigid import RigidBodies, rotation_exp, skew
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import BoxBoundary, ContactSettings, Domain, GroundBoundary
from fracture_gs.testing.lattice import LatticeBody, lattice_box, lattice_sphere, particle_set

pytestmark = pytest.mark.extension  # tests/conftest.py: skipped without _C, failed in CI

BALL = ElasticMaterial(E=2.0e5, nu=0.3, density=1.0e3)
# Steel: as an elastic body on this grid its wave speed (~5.9 km/s) would make the step ~40x shorter.
STEEL = ElasticMaterial(E=2.0e11, nu=0.3, density=7.8e3)


def random_body(seed: int) -> tuple[RigidBodies, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    x = torch.rand(400, 3, generator=generator, dtype=torch.float64).float() * torch.tensor([0.3, 0.1, 0.05])
    mass = 0.5 + torch.rand(400, generator=generator)
    bodies = RigidBodies([0], x, mass, torch.zeros(400, dtype=torch.int32), dx=0.02)
    return bodies, x, mass


def axial(matrices: torch.Tensor) -> torch.Tensor:
    """(n, 3): a_k = ε_kij M_ji of each matrix (twice the axial vector of its skew part)."""
    return torch.stack((matrices[:, 2, 1] - matrices[:, 1, 2], matrices[:, 0, 2] - matrices[:, 2, 0],
                        matrices[:, 1, 0] - matrices[:, 0, 1]), dim=1)


def apic_momenta(bodies: RigidBodies, x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, mass: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Linear and angular momentum about the origin and the APIC kinetic energy ½ Σ m (|v|² + D |C|²)."""
    m = mass.double()[:, None]
    xd, vd, Cd = x.double(), v.double(), C.double()
    linear = (m * vd).sum(0)
    angular = (m * torch.cross(xd, vd, dim=1)).sum(0) + bodies.affine * (m * axial(Cd)).sum(0)
    energy = 0.5 * float((m[:, 0] * ((vd * vd).sum(1) + bodies.affine * (Cd * Cd).sum((1, 2)))).sum())
    return linear, angular, energy


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_projection_keeps_momentum_and_angular_momentum_and_removes_energy(seed):
    bodies, x, mass = random_body(seed)
    generator = torch.Generator().manual_seed(100 + seed)
    v = torch.randn(len(x), 3, generator=generator)
    C = torch.randn(len(x), 3, 3, generator=generator)
    dt = 1e-4
    # The G2P result the projection sees: the particles moved by dt v (angular momentum is kept about
    # the body's centre at the step's start; the origin's share follows from the momentum).
    before = apic_momenta(bodies, x, v, C, mass)
    centre0 = torch.as_tensor(bodies.bodies[0].centre.copy())
    x_new, v_new, C_new = x + dt * v, v.clone(), C.clone()
    F, stress = torch.eye(3).expand(len(x), 3, 3).contiguous(), torch.ones(len(x), 3, 3)
    bodies.project(x_new, v_new, C_new, F, stress, torch.arange(len(x)), dt)  # no ground: no impulse
    after = apic_momenta(bodies, x_new, v_new, C_new, mass)
    linear = before[0]
    assert torch.allclose(after[0], linear, rtol=1e-5, atol=1e-5 * float(linear.norm()))
    # angular momentum about the moving centre: L_origin - c × P at the start and at the end
    start = before[1] - torch.cross(centre0, linear, dim=0)
    end = after[1] - torch.cross(torch.as_tensor(bodies.bodies[0].centre), after[0], dim=0)
    assert torch.allclose(end, start, rtol=1e-5, atol=1e-5 * float(start.norm()))
    assert after[2] < before[2]
    assert float(stress.abs().max()) == 0.0
    assert torch.allclose(F[0] @ F[0].T, torch.eye(3), atol=1e-6)


def test_projection_leaves_a_rigid_motion_alone():
    bodies, x, mass = random_body(3)
    spin, linear = torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64), torch.tensor([1.0, 0.5, -2.0])
    centre = torch.as_tensor(bodies.bodies[0].centre)
    v = (linear.double() + torch.cross(spin.expand(len(x), 3), x.double() - centre, dim=1)).float()
    C = torch.as_tensor(skew(spin.numpy())).float().expand(len(x), 3, 3).contiguous()
    dt = 1e-4
    x_new, v_new, C_new = x.clone(), v.clone(), C.clone()
    bodies.project(x_new, v_new, C_new, torch.eye(3).expand(len(x), 3, 3).contiguous(), torch.zeros(len(x), 3, 3),
                   torch.arange(len(x)), dt)
    expected = centre + dt * linear.double() + (x.double() - centre) @ torch.as_tensor(rotation_exp(dt * spin.numpy())).T
    assert torch.allclose(x_new.double(), expected, atol=1e-6)
    # the spin of a non-symmetric body turns by O(dt |ω|²) as its inertia turns (L is what is kept)
    assert torch.allclose(v_new, v, atol=1e-3)
    assert torch.allclose(C_new, C, atol=1e-3)


def struck_bar(backend: str = "auto", gravity: tuple[float, float, float] = (0.0, 0.0, 0.0),
               ground: bool = False) -> CollisionMPM:
    """A steel bar (rigid) lying along x, struck near its +x end by a soft ball moving down."""
    domain = Domain((0, 0, 0), (1, 1, 1), 32)
    spacing = domain.dx / 2
    bar_height = 0.3 if ground else 0.4
    bar = lattice_box((0.5, 0.5, bar_height), (0.6, 0.1, 0.1), spacing)
    # the ball (radius 0.06) 1.5 cells above the bar's top face (half-thickness 0.05)
    ball = lattice_sphere((0.72, 0.5, bar_height + 0.05 + 0.06 + 1.5 * domain.dx), 0.06, spacing)
    bodies = [LatticeBody(bar, (0, 0, 0), 0, spacing), LatticeBody(ball, (0, 0, -3.0), 1, spacing)]
    return CollisionMPM(particle_set(bodies, [STEEL.density, BALL.density]), [STEEL, BALL], domain,
                        contact=ContactSettings(), gravity=gravity, backend=backend, rigid_objects=[0],
                        boundaries=[GroundBoundary(height=0.1, friction=0.3)] if ground else ())


def body_state(solver: CollisionMPM, obj: int) -> tuple[np.ndarray, np.ndarray]:
    state = solver.state_in_input_order()
    sel = (solver.input_particles.obj_id == obj).numpy()
    return state.x.double().numpy()[sel], state.v.double().numpy()[sel]


def test_rigid_fit_residual_is_zero_for_a_rigid_motion_and_the_strain_for_a_stretch():
    rest = np.random.default_rng(0).normal(size=(500, 3))
    turn = rotation_exp(np.array([0.3, -0.8, 1.1]))
    assert rigid_fit_residual(rest, rest @ turn.T + [1.0, 2.0, 3.0]) < 1e-12
    stretched = rest * [1.1, 1.0, 1.0]
    assert 0.02 < rigid_fit_residual(rest, stretched) < 0.1


def test_rigid_object_sets_no_time_step():
    solver = struck_bar()
    assert solver.max_wave_speed == pytest.approx(BALL.wave_speed)
    assert STEEL.wave_speed > 20 * BALL.wave_speed


def test_struck_rigid_bar_moves_as_one_body_keeps_momentum_and_lets_the_ball_go():
    solver = struck_bar()
    rest, _ = body_state(solver, 0)
    diag0 = solver.diagnostics()
    p0, e0 = np.asarray(diag0["momentum"]), diag0["total_energy"]
    scale = float((solver.particles.mass.double() * solver.state.v.double().norm(dim=1)).sum())
    peak, drift, first_motion = e0, 0.0, None
    for step in range(400):
        solver.step(solver.stable_dt())
        x, v = body_state(solver, 0)
        if first_motion is None and np.abs(v[:, 2]).max() > 1e-6:
            near = x[:, 0] > 0.7    # the struck end, and the far end 0.4 m away
            first_motion = (float(v[near, 2].mean()), float(v[x[:, 0] < 0.3, 2].mean()), step)
        if step % 20 == 0:
            diagnostics = solver.diagnostics()
            peak = max(peak, diagnostics["total_energy"])
            drift = max(drift, float(np.linalg.norm(np.asarray(diagnostics["momentum"]) - p0)) / scale)
    x, v = body_state(solver, 0)
    ball_x, ball_v = body_state(solver, 1)
    print(f"[rigid bar] first motion near/far {first_motion}, drift {drift:.2e}, energy {e0:.4g} -> peak {peak:.4g}, "
          f"residual {rigid_fit_residual(rest, x):.2e}, ball vz {ball_v[:, 2].mean():+.3f}, bar vz {v[:, 2].mean():+.3f}")
    assert first_motion is not None
    near, far, _ = first_motion
    # the whole bar answers the blow in the same substep: the struck end moves down, the far end up
    # (the bar turns about its mass centre), no wave has to cross it
    assert near < 0 and far > 0
    assert drift <= 1e-5
    assert peak <= e0 * 1.01
    assert rigid_fit_residual(rest, x) < 1e-5
    spin_axis = np.cross(x[-1] - x.mean(0), v[-1] - v.mean(0))
    assert v[:, 2].mean() < -0.05 and np.sign(spin_axis[1]) != 0
    # the ball bounced off (no sticking) and stays above the bar (no passing through)
    assert ball_v[:, 2].mean() > v[:, 2].mean() + 0.05
    assert ball_x[:, 2].min() > x[:, 2].max() - solver.geometry.dx


def test_rigid_bar_rests_on_the_ground():
    solver = struck_bar(gravity=(0.0, 0.0, -9.8), ground=True)
    solver.state.x[solver.particles.obj_id == 1] += torch.tensor([0.0, 0.0, 0.3])  # the ball out of the way
    rest, _ = body_state(solver, 0)
    bottom0 = rest[:, 2].min()
    solver.advance(0.3)   # falls 0.15 m and lands
    x, v = body_state(solver, 0)
    print(f"[rigid bar on the ground] bottom {x[:, 2].min():.4f} (ground 0.1), speed {np.abs(v).max():.3g}, "
          f"residual {rigid_fit_residual(rest, x):.2e}")
    assert bottom0 > 0.2
    assert abs(x[:, 2].min() - 0.1) < 0.5 * solver.geometry.dx
    assert np.abs(v).max() < 0.05
    assert rigid_fit_residual(rest, x) < 1e-5


@pytest.mark.parametrize("walls", ["slip", "sticky"])
def test_rigid_box_thrown_at_a_wall_stops_there_and_balances_momentum(walls):
    domain = Domain((0, 0, 0), (1, 1, 1), 32)
    spacing = domain.dx / 2
    box = lattice_box((0.7, 0.5, 0.5), (0.2, 0.15, 0.1), spacing)
    solver = CollisionMPM(particle_set([LatticeBody(box, (5.0, 1.0, 0.0), 0, spacing)], [STEEL.density]), [STEEL],
                          domain, gravity=(0.0, 0.0, 0.0), boundaries=[BoxBoundary(walls)], rigid_objects=[0])
    rest, _ = body_state(solver, 0)
    p0 = np.asarray(solver.diagnostics()["momentum"])
    solver.advance(0.1)   # reaches the wall (0.1 m away) after 0.02 s
    x, v = body_state(solver, 0)
    diagnostics = solver.diagnostics()
    balance = np.linalg.norm(np.asarray(diagnostics["momentum"]) - p0 - np.asarray(diagnostics["external_impulse"]))
    wall = solver.geometry.clamp_bounds()[1][0]
    print(f"[rigid box at a {walls} wall] front {x[:, 0].max():.4f} (wall {wall:.4f}), velocity {v.mean(0).round(3)}, "
          f"balance {balance / np.linalg.norm(p0):.2e}")
    assert x[:, 0].max() <= wall + 1e-4
    assert v[:, 0].mean() <= 1e-3                    # stopped at the wall, not pushed into it
    assert balance <= 1e-5 * np.linalg.norm(p0)
    assert rigid_fit_residual(rest, x) < 1e-5
    if walls == "sticky":
        assert abs(v[:, 1].mean()) < 1e-3           # no sliding along a sticky wall
    else:
        assert v[:, 1].mean() > 0.5                  # sliding on along a slip wall


def test_rigid_body_resumes_bit_identically():
    first = struck_bar()
    for _ in range(30):
        first.step(first.stable_dt())
    saved = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in first.state_dict().items()}
    assert "rigid_centre" in saved and "rigid_rotation" in saved
    for _ in range(40):
        first.step(first.stable_dt())
    second = struck_bar()
    second.load_state_dict(saved)
    for _ in range(40):
        second.step(second.stable_dt())
    assert torch.equal(first.state.x, second.state.x) and torch.equal(first.state.v, second.state.v)
    assert torch.equal(first.state.F_E, second.state.F_E)


def test_checkpoint_without_rigid_state_is_refused():
    solver = struck_bar()
    saved = solver.state_dict()
    del saved["rigid_centre"]
    with pytest.raises(KeyError, match="rigid"):
        struck_bar().load_state_dict(saved)


SCENE = {"name": "s", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
         "objects": [{"name": "slab", "rigid": True, "primitive": {"shape": "box", "size": [0.3, 0.3, 0.1]},
                      "transform": {"translate": [0.5, 0.5, 0.5]},
                      "materials": [{"part": 0, "model": "elastic", "E": 1e9, "nu": 0.3, "density": 2000}]}]}


def test_scene_rigid_key_round_trips_and_refuses_breaking_materials():
    config = parse_scene(SCENE)
    assert config.objects[0].rigid and config.to_dict()["objects"][0]["rigid"] is True
    assert parse_scene(config.to_dict()) == config
    plain = parse_scene({**SCENE, "objects": [{k: v for k, v in SCENE["objects"][0].items() if k != "rigid"}]})
    assert "rigid" not in plain.to_dict()["objects"][0]   # scenes written before the key compare equal
    brittle = {**SCENE["objects"][0], "materials": [{"part": 0, "preset": "porcelain"}]}
    with pytest.raises(SceneError, match=r"objects\[0\]\.materials\[0\]\.model: a rigid object"):
        parse_scene({**SCENE, "objects": [brittle]})
    with pytest.raises(SceneError, match=r"objects\[0\]\.rigid: expected true or false"):
        parse_scene({**SCENE, "objects": [{**SCENE["objects"][0], "rigid": "yes"}]})


def test_scene_of_rigid_objects_alone_takes_finite_steps():
    from fracture_gs.mpm.scene import build_scene

    built = build_scene(parse_scene({**SCENE, "gravity": [0, 0, -9.8]}))
    solver = CollisionMPM(built.particles, built.materials, built.domain, gravity=built.gravity,
                          rigid_objects=built.rigid_objects)
    dt = solver.stable_dt()
    assert math.isfinite(dt) and dt > 0
    solver.advance(0.05)
    assert float(solver.state.v[:, 2].mean()) == pytest.approx(-9.8 * 0.05, rel=1e-3)
