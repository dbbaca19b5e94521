"""The Collision-MPM step side by side with GaussianFluent's NACC solver on NVIDIA Warp's CPU backend (prints JSON).

GaussianFluent (github.com/HB-pencil-zero/GaussianFluent) is not part of this repository: pass
the path of your checkout and its ``mpm_solver_warp`` is imported from there at run time. Its
code runs as written on Warp 1.7 (``pip install warp-lang==1.7.2``; later releases dropped the
``warp.torch`` module and the ``owner=`` argument it uses), with these done from the
outside, none of them edits of its files:

* its loader ``load_initial_data_from_torch`` passes the device where ``clone`` is expected
  (it would ask for ``cuda:0``), so the benchmark does the loader's steps itself with the device
  by keyword; its ``set_parameters`` passes its arguments to ``set_parameters_dict`` in the wrong
  order, so ``set_parameters_dict`` is called directly;
* its G2P kernel ``g2p_flip`` divides each stencil node's momentum by the node's mass, which is
  zero where no particle reaches the node with a weight above zero (0/0: the particle's velocity
  becomes NaN). The kernel is rebuilt from its own source with one AST change, Warp's
  ``code_transformers`` hook: the divisor ``state.grid_m[ix, iy, iz]`` becomes
  ``wp.max(state.grid_m[ix, iy, iz], 1e-30)``. A node without mass has no momentum either, so it
  now adds 0 instead of NaN; every node with a mass above 1e-30 (every node a particle reaches)
  gives what it gave before. The solver module's ``g2p_flip`` is rebound to that kernel.

Scene: ``bench_mpm.py``'s two spheres (the same particles in the same order, velocities, masses and
volumes, grid and domain, gravity, walls), GaussianFluent's NACC (its material 7) with the same
E, ν, density, α0 (its ``alpha_0``, the initial ln J_p), β, ξ and M and hardening on; its
transfer is the one its NACC scene uses (FLIP kernels with ``flip_pic_ratio`` 0). Every step of
GaussianFluent takes the time step that our NACC solver without crack opening took at the same
step (our ``stable_dt``). Three of our solvers (compiled backend, the OpenMP threads of this
process) are timed: NACC with cracks not opening and opening, brittle with cracks opening;
GaussianFluent has one NACC step, which each of them is compared with. All four take turns, one
block of --steps steps each per round (``bench_mpm.measure``), so that the machine's drift falls on
all alike; the JSON gives per configuration both sides' median block and range, the ratio of the
medians, the median and range of the per-round ratios and the ratio of the two fastest blocks (the
one least disturbed by other processes: they slow our parallel loops, which wait for their slowest
thread, far more than Warp's one thread). Warp's CPU backend runs a kernel's
threads one after another on one core; the JSON records our thread count.

``same_scene`` checks that the two runs are the same physical scene: after the same steps, each
sphere's centre of mass displacement and mean velocity and the total momentum of our NACC solver
(cracks not opening) and of GaussianFluent's; and how many particles GaussianFluent's unguarded
G2P gives a non-finite velocity in the scene's first step.

    OMP_NUM_THREADS=2 python benchmarks/bench_gaussianfluent.py --gaussianfluent PATH [--particles 50000 200000]
"""
from __future__ import annotations

import argparse
import ast
import contextlib
import hashlib
import importlib
import json
import os
import statistics
import sys
from pathlib import Path
from types import ModuleType

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the benchmarks folder
from bench_mpm import MATERIALS, measure, ratio_entry, result_row, two_spheres  # noqa: E402

SOLVER_FILES = ("mpm_solver_warp.py", "mpm_utils.py", "warp_utils.py")
CONFIGS = (("nacc", False), ("nacc", True), ("brittle", True))  # ours: material, cracks opening
WARMUP_STEPS = 40  # as bench_mpm.run_timed: the spheres press into each other before the timing
MASS_FLOOR = 1e-30  # the divisor's floor in GaussianFluent's patched G2P


class BadInput(Exception):
    """A command-line argument or the GaussianFluent checkout cannot be used."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line, checked: one BadInput line for a bad value or checkout."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussianfluent", type=Path, required=True,
                        help="a GaussianFluent checkout (the folder that holds mpm_solver_warp/)")
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--particles", type=int, nargs="+", default=[50_000, 200_000])
    parser.add_argument("--steps", type=int, default=10, help="steps per timed block, each solver")
    parser.add_argument("--repeats", type=int, default=15, help="timed blocks per solver; the median is reported")
    args = parser.parse_args(argv)
    solver_dir = args.gaussianfluent / "mpm_solver_warp"
    missing = [name for name in SOLVER_FILES if not (solver_dir / name).is_file()]
    if missing:
        raise BadInput(f"--gaussianfluent {args.gaussianfluent}: no {solver_dir / missing[0]} "
                       "(pass a GaussianFluent checkout)")
    if args.grid < 16:
        raise BadInput(f"--grid {args.grid}: at least 16")
    if min(args.particles) < 100:
        raise BadInput(f"--particles {min(args.particles)}: at least 100")
    if args.steps < 1 or args.repeats < 1:
        raise BadInput(f"--steps {args.steps} --repeats {args.repeats}: both at least 1")
    return args


class _GuardGridMassDivision(ast.NodeTransformer):
    """Rewrites every ``a / state.grid_m[...]`` into ``a / wp.max(state.grid_m[...], floor)``."""

    def __init__(self, floor: float) -> None:
        self.floor = floor
        self.replaced = 0

    def visit_BinOp(self, node: ast.BinOp) -> ast.BinOp:
        self.generic_visit(node)
        divisor = node.right
        if (isinstance(node.op, ast.Div) and isinstance(divisor, ast.Subscript)
                and isinstance(divisor.value, ast.Attribute) and divisor.value.attr == "grid_m"):
            call = ast.Call(func=ast.Attribute(value=ast.Name(id="wp", ctx=ast.Load()), attr="max", ctx=ast.Load()),
                            args=[divisor, ast.Constant(value=self.floor)], keywords=[])
            node.right = ast.fix_missing_locations(ast.copy_location(call, divisor))
            self.replaced += 1
        return node


def load_gaussianfluent(checkout: Path) -> tuple[ModuleType, ModuleType]:
    """(warp, GaussianFluent's mpm_solver_warp module with its G2P guarded), imported from the checkout."""
    try:
        import warp
    except ImportError as exc:
        raise BadInput(f"Warp is not installed ({exc}): pip install warp-lang==1.7.2") from exc
    warp.config.quiet = True
    warp.init()
    sys.path.insert(0, str(checkout / "mpm_solver_warp"))
    try:
        solver_module = importlib.import_module("mpm_solver_warp")
    except (ImportError, AttributeError) as exc:
        raise BadInput(f"GaussianFluent's solver does not import under Warp {warp.__version__} ({exc}); "
                       "it runs on warp-lang 1.7.2") from exc
    utils = sys.modules["mpm_utils"]
    guard = _GuardGridMassDivision(MASS_FLOOR)
    guarded = warp.context.Kernel(utils.g2p_flip.func, key="g2p_flip_grid_mass_floor",
                                  code_transformers=[guard])
    if guard.replaced != 1:
        raise BadInput(f"GaussianFluent's g2p_flip has {guard.replaced} divisions by grid_m, expected 1: "
                       "a different version of its solver")
    solver_module.g2p_flip = guarded  # p2g2p launches the module global
    return warp, solver_module


def solver_digest(checkout: Path) -> str:
    """sha256 of GaussianFluent's solver files: which code was measured."""
    digest = hashlib.sha256()
    for name in SOLVER_FILES:
        digest.update((checkout / "mpm_solver_warp" / name).read_bytes())
    return digest.hexdigest()


class DtRecorder:
    """Our solver with a record of the time step of each of its steps (every other attribute is the solver's)."""

    def __init__(self, solver) -> None:
        self.solver = solver
        self.dts: list[float] = []

    def step(self, dt: float) -> None:
        self.dts.append(dt)
        self.solver.step(dt)

    def __getattr__(self, name: str):
        return getattr(self.solver, name)


class GaussianFluentNACC:
    """GaussianFluent's MPM_Simulator_WARP on Warp's CPU device, loaded with our particles, with the
    interface ``bench_mpm.measure`` times: ``step(dt)``, ``stable_dt()`` (the dt our paired solver
    took at the same step), ``device``, ``last_split_mask``, ``particles``."""

    def __init__(self, warp: ModuleType, module: ModuleType, paired: DtRecorder, grid: int) -> None:
        particles = paired.input_particles
        material = paired.materials[0]
        gravity = paired.gravity
        self.warp, self.paired, self.particles = warp, paired, particles
        self.device = torch.device("cpu")
        self.last_split_mask = None
        self.steps = 0
        lower, upper = paired.domain.lower, paired.domain.upper
        if any(lo != 0 for lo in lower) or len(set(hi - lo for lo, hi in zip(lower, upper))) != 1:
            raise ValueError("GaussianFluent's domain is [0, grid_lim]^3: the scene's domain must be a cube at 0")
        side = float(upper[0] - lower[0])
        n = len(particles)
        sim = module.MPM_Simulator_WARP(n, n_grid=grid, grid_lim=side, device="cpu")
        # load_initial_data_from_torch's steps, with the device by keyword.
        sim.import_particle_x_from_torch(particles.x.float().contiguous(), device="cpu")
        sim.import_particle_v_from_torch(particles.v.float().contiguous(), device="cpu")
        sim.mpm_state.particle_vol = warp.from_numpy(particles.rest_volume.numpy(), dtype=float, device="cpu")
        warp.launch(kernel=module.set_mat33_to_identity, dim=n, inputs=[sim.mpm_state.particle_F_trial],
                    device="cpu")
        density = float(material.density)
        sim.set_parameters_dict({
            "material": "watermelon",  # its material 7: NACC
            "grid_lim": side, "n_grid": grid, "E": float(material.E), "nu": float(material.nu),
            "density": density, "alpha_0": float(material.alpha0), "beta": float(material.beta),
            "xi": float(material.xi), "hardening": 1.0, "g": [float(g) for g in gravity],
        }, device="cpu")
        sim.mpm_model.M = float(material.M)  # set_parameters_dict derives M from a friction angle only
        sim.finalize_mu_lam(device="cpu")
        sim.add_bounding_box()
        if not torch.allclose(torch.from_numpy(sim.mpm_state.particle_mass.numpy()), particles.mass.float(),
                              rtol=1e-5):
            raise ValueError("GaussianFluent's particle masses differ from ours")
        self.sim = sim

    def stable_dt(self) -> float:
        if self.steps >= len(self.paired.dts):
            raise RuntimeError("GaussianFluent ran ahead of the solver whose time steps it takes")
        return self.paired.dts[self.steps]

    def step(self, dt: float) -> None:
        self.sim.p2g2p(self.steps, dt, device="cpu", flip_pic_ratio=0.0)
        self.warp.synchronize_device("cpu")
        self.steps += 1

    def positions_velocities(self) -> tuple[torch.Tensor, torch.Tensor]:
        return (torch.from_numpy(self.sim.mpm_state.particle_x.numpy()).double(),
                torch.from_numpy(self.sim.mpm_state.particle_v.numpy()).double())


def unguarded_first_step(warp: ModuleType, module: ModuleType, paired: DtRecorder, grid: int) -> int:
    """Particles whose velocity GaussianFluent's own G2P (without the guard) makes non-finite in the
    first step of the scene. Only one step: the next P2G would write at NaN positions."""
    guarded = module.g2p_flip
    module.g2p_flip = sys.modules["mpm_utils"].g2p_flip
    try:
        solver = GaussianFluentNACC(warp, module, paired, grid)
        solver.step(solver.stable_dt())
        _, velocity = solver.positions_velocities()
        return int((~torch.isfinite(velocity).all(1)).sum())
    finally:
        module.g2p_flip = guarded


def motion(x: torch.Tensor, v: torch.Tensor, x0: torch.Tensor, mass: torch.Tensor, obj: torch.Tensor) -> dict:
    """Per sphere: centre of mass displacement and mean velocity; total momentum; particles with NaN."""
    mass = mass.double()
    spheres = []
    for body in (0, 1):
        keep = obj == body
        m = mass[keep]
        shift = ((x[keep] - x0[keep]) * m[:, None]).sum(0) / m.sum()
        velocity = (v[keep] * m[:, None]).sum(0) / m.sum()
        spheres.append({"centre_displacement": [round(float(c), 6) for c in shift],
                        "mean_velocity": [round(float(c), 4) for c in velocity]})
    return {"spheres": spheres,
            "momentum": [round(float(c), 6) for c in (v * mass[:, None]).sum(0)],
            "nan_particles": int((~torch.isfinite(x).all(1) | ~torch.isfinite(v).all(1)).sum())}


def same_scene(ours: DtRecorder, theirs: GaussianFluentNACC) -> dict:
    """Both runs' motion after the same steps, particles in the constructor's order."""
    state = ours.state_in_input_order()
    start = theirs.particles
    their_x, their_v = theirs.positions_velocities()
    return {"steps": theirs.steps, "simulated_time_s": round(float(sum(ours.dts)), 7),
            "ours": motion(state.x.double(), state.v.double(), start.x.double(), start.mass, start.obj_id),
            "gaussianfluent": motion(their_x, their_v, start.x.double(), start.mass, start.obj_id)}


def block_row(solver: GaussianFluentNACC, steps: int, repeats: int, blocks: list[float]) -> dict:
    seconds = statistics.median(blocks)
    n = len(solver.particles)
    return {"backend": "gaussianfluent-warp-cpu", "material": "nacc", "fragments": False, "particles": n,
            "steps": steps, "repeats": repeats, "ms_per_step": round(1e3 * seconds, 3),
            "particle_steps_per_s": round(n / seconds),
            "particle_steps_per_s_range": [round(n / max(blocks)), round(n / min(blocks))]}


def run_size(n: int, args: argparse.Namespace, warp: ModuleType, module: ModuleType) -> tuple[list[dict], dict]:
    """Our three solvers and GaussianFluent's at ~n particles, warmed up alike, timed in turns."""
    device = torch.device("cpu")
    ours = []
    for material, fragments in CONFIGS:
        solver = DtRecorder(two_spheres(n, args.grid, device, "cpp", fragments, material))
        for _ in range(WARMUP_STEPS):
            solver.step(solver.stable_dt())
        ours.append(solver)
    unguarded_nan = unguarded_first_step(warp, module, ours[0], args.grid)
    theirs = GaussianFluentNACC(warp, module, ours[0], args.grid)
    for _ in range(WARMUP_STEPS):
        theirs.step(theirs.stable_dt())
    alpha_starts = [solver.state.alpha.clone() for solver in ours]
    timed = measure([*ours, theirs], args.steps, args.repeats)
    their_blocks = timed[-1][0]
    their_row = block_row(theirs, args.steps, args.repeats, their_blocks)
    rows = []
    for (material, fragments), solver, alpha_start, (blocks, split_share) in zip(CONFIGS, ours, alpha_starts, timed):
        ours_row = result_row(solver.solver, "cpp", material, fragments, args.steps, args.repeats, blocks,
                              split_share, alpha_start)
        rows.append({"configuration": {"material": material, "fragments": fragments},
                     "particles": ours_row["particles"], "ours": ours_row, "gaussianfluent": their_row,
                     "gaussianfluent_over_ours": {**ratio_entry(ours_row["particles"], their_blocks, blocks),
                                                  "fastest_block_ratio": round(min(their_blocks) / min(blocks), 3)}})
    return rows, {**same_scene(ours[0], theirs), "unguarded_g2p_nan_particles_first_step": unguarded_nan}


def main(argv: list[str] | None = None) -> int:
    from fracture_gs._backend import compiled_module

    json_out = sys.stdout
    with contextlib.redirect_stdout(sys.stderr):  # Warp prints its notices on stdout; the JSON goes there alone
        try:
            args = parse_args(argv)
            if compiled_module() is None:
                raise BadInput("the compiled extension is not built (bash install.sh)")
            warp, module = load_gaussianfluent(args.gaussianfluent)
        except BadInput as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        results, scenes, load = [], [], []
        for n in args.particles:
            before = os.getloadavg()[0]
            rows, scene = run_size(n, args, warp, module)
            load.append({"particles": rows[0]["particles"], "load_average_1min": [round(before, 2),
                                                                                   round(os.getloadavg()[0], 2)]})
            results += rows
            scenes.append({"particles": rows[0]["particles"], **scene})
            print(f"{rows[0]['particles']:,} particles: GaussianFluent / ours = "
                  + ", ".join(f"{row['configuration']['material']} fragments {row['configuration']['fragments']}: "
                              f"{row['gaussianfluent_over_ours']['ratio']:.1f}x" for row in rows), file=sys.stderr)
    print(json.dumps({
        "benchmark": "mpm_step_vs_gaussianfluent", "grid": args.grid, "device": "cpu",
        "threads": int(compiled_module().openmp_max_threads()), "torch_threads": torch.get_num_threads(),
        "warp": warp.__version__, "warp_mode": warp.config.mode,
        "gaussianfluent_solver_sha256": solver_digest(args.gaussianfluent),
        "gaussianfluent_g2p_guard": f"g2p_flip's divisor state.grid_m[ix, iy, iz] -> "
                                    f"wp.max(state.grid_m[ix, iy, iz], {MASS_FLOOR:g})",
        "gaussianfluent_transfer": "p2g_flip_pic_with_stress + g2p_flip, flip_pic_ratio 0",
        # The machine's 1-minute load average before and after each size: other processes on the cores
        # slow our OpenMP threads far more than Warp's one thread.
        "machine_load": load,
        "results": results, "same_scene": scenes}, indent=2), file=json_out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
