"""Every number a user can type has a range (fracture_gs/bounds.py, docs/scenes.md, docs/materials.md):
out-of-range seeds, speeds, moduli, densities, strengths, Weibull moduli, softening factors and frame
rates stop with one line naming the key or option and exit status 2, before anything is written; a
scene whose CFL substeps would be absurd is refused before it runs; a YAML nested thousands deep, a
scene file whose name is no valid name and a full disk are one clear line each."""
from __future__ import annotations

import errno
import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import yaml

from fracture_gs import bounds
from fracture_gs.cli import render as render_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli import view as view_cli
from fracture_gs.cli.train import main as train_main
from fracture_gs.config.scene import SceneError, load_scene, parse_scene
from fracture_gs.data.synthetic import __main__ as synthetic_cli
from fracture_gs.data.synthetic import generator
from fracture_gs.io.atomic import atomic_write
from fracture_gs.io.output_folder import os_error_line
from fracture_gs.materials import BrittleMaterial, MaterialTable
from fracture_gs.materials.brittle import FRACTURE_ENERGY_RANGE, WEIBULL_M_RANGE
from fracture_gs.mpm.scene import build_scene
from fracture_gs.mpm.substeps import check_substeps, estimate_substeps
from fracture_gs.pipeline.experiments.sim_report import print_comparison
from fracture_gs.pipeline.simulate import create_solver
from fracture_gs.render import video

ROOT = Path(__file__).resolve().parents[1]
TRAIN_FIXTURE = ROOT / "tests" / "data" / "synthetic_fixture"


def particle_strengths(materials: list, material_id: torch.Tensor, rest_volume: torch.Tensor,
                       seed: int) -> torch.Tensor:
    """Every particle's tensile strength as the scene's state block starts with it."""
    state = MaterialTable(materials, cell_size=1.0).initial_state(material_id, rest_volume, seed)
    return state[:, BrittleMaterial.state_fields.index("strength")]


def brittle_sphere(**material: Any) -> dict[str, Any]:
    """A small brittle sphere in free flight on a 16³ grid (a few hundred particles)."""
    keys = {"part": 0, "model": "brittle", "E": 2.0e6, "nu": 0.2, "density": 100.0,
            "strength": 2.0e4, "fracture_energy": 2.0, "weibull_m": 6}
    keys.update(material)
    return {"name": "ranges", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
            "frames": 1, "frame_dt": 0.01,
            "objects": [{"name": "ball", "primitive": {"shape": "sphere", "radius": 0.15},
                         "transform": {"translate": [0.5, 0.5, 0.5]}, "materials": [keys]}]}


def refusal(scene: dict[str, Any]) -> str:
    with pytest.raises(SceneError) as caught:
        parse_scene(scene)
    return str(caught.value)


def simulate_refused(tmp_path: Path, scene: dict[str, Any] | str, capsys: pytest.CaptureFixture[str],
                     name: str = "scene.yaml") -> str:
    """simulate.py on the scene: exit 2, one 'error:' line, no output folder; returns the line."""
    path = tmp_path / name
    path.write_text(scene if isinstance(scene, str) else yaml.safe_dump(scene))
    out = tmp_path / "sim"
    assert simulate_cli.main(["--scene", str(path), "--out", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and "Traceback" not in err, err
    assert not out.exists()
    return err.strip()


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("error: "), err
    return err.strip()


def small_simulation(root: Path) -> Path:
    """A simulation folder of a small block at rest (frames 0..2) and its model folder."""
    from render_scenes import block_scene, identity_frames, lattice_block, write_model, write_sim

    points, surface = lattice_block((0.04, 0.04, 0.04))
    write_model(root / "model", points, surface)
    rest = (0.5 + points).astype(np.float32)
    count = points.shape[0]
    return write_sim(root / "sim", block_scene(root / "model"),
                     {"rest_x": rest, "obj_id": np.zeros(count, np.int32), "is_surface": surface,
                      "gaussian_index": np.where(surface, np.cumsum(surface) - 1, -1),
                      "rest_volume": np.full(count, 2.7e-5, np.float32)}, identity_frames(rest, 3))


def disk_full(*args: Any, **kwargs: Any) -> None:
    """What a write on a full disk raises: the reason, no file name."""
    raise OSError(errno.ENOSPC, "No space left on device")


# ----------------------------------------------------------------------------- seeds (findings 10, 11)


@pytest.mark.parametrize("seed, problem", [(2 ** 65, f"seed: {2 ** 65} is not <= {2 ** 64 - 1}"),
                                           (-1, "seed: -1 is not >= 0")])
def test_a_scene_seed_outside_64_bits_is_one_line(seed: int, problem: str, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    scene = brittle_sphere()
    scene["seed"] = seed
    assert simulate_refused(tmp_path, scene, capsys) == f"error: {problem}"


def test_the_largest_seed_gives_weibull_strengths() -> None:
    scene = brittle_sphere()
    scene["seed"] = bounds.SEED_MAX
    config = parse_scene(scene)
    built = build_scene(config, torch.device("cpu"))
    largest = particle_strengths(built.materials, built.particles.material_id, built.particles.rest_volume,
                                 config.seed)
    first = particle_strengths(built.materials, built.particles.material_id, built.particles.rest_volume, 0)
    assert largest is not None and first is not None
    assert bool(torch.isfinite(largest).all()) and not torch.equal(largest, first)


@pytest.mark.parametrize("seed", ["-1", str(2 ** 64)])
def test_train_seed_outside_64_bits_is_one_line(seed: str, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "model"
    assert train_main(["-s", str(TRAIN_FIXTURE), "-m", str(model), "--seed", seed, "--quiet"]) == 2
    assert one_error_line(capsys) == f"error: --seed: {seed} must be within [0, {2 ** 64 - 1}]"
    assert not model.exists()


# ----------------------------------------------------------------------------- frame rates (finding 12)


@pytest.mark.parametrize("fps", ["inf", "nan", "0", "1e6"])
def test_render_and_view_fps_must_be_finite_and_sensible(fps: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    expected = f"error: --fps {float(fps):g}: must be within [0.1, 1000]"
    assert render_cli.main(["--sim", str(tmp_path / "sim"), "--fps", fps]) == 2
    assert one_error_line(capsys) == expected
    assert view_cli.main([str(tmp_path / "sim"), "--fps", fps]) == 2
    assert one_error_line(capsys) == expected
    assert list(tmp_path.iterdir()) == []


def test_a_video_writer_that_cannot_start_leaves_no_temporary_file(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import imageio_ffmpeg

    def broken(*args: Any, **kwargs: Any) -> None:
        raise OverflowError("cannot convert float infinity to integer")

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", broken)
    with pytest.raises(OverflowError):
        video.Mp4Writer(tmp_path / "video.mp4", 16, 16, 30.0)
    assert list(tmp_path.iterdir()) == []


def test_a_render_that_fails_at_its_second_video_leaves_no_temporary_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    sim = small_simulation(tmp_path)
    original = video.Mp4Writer.__init__
    started: list[Path] = []

    def second_fails(self: video.Mp4Writer, path: Path, width: int, height: int, fps: float) -> None:
        if started:
            raise OSError(errno.EMFILE, "Too many open files")
        started.append(path)
        original(self, path, width, height, fps)

    monkeypatch.setattr(video.Mp4Writer, "__init__", second_fails)
    assert render_cli.main(["--sim", str(sim), "--views", "orbit:2", "--resolution", "16", "16"]) == 1
    assert one_error_line(capsys) == "error: Too many open files"
    assert started and not list(sim.rglob("*.tmp*")) and not list(sim.rglob("*.mp4"))


# ----------------------------------------------------------------------------- YAML nesting (finding 13)


def test_a_yaml_nested_thousands_deep_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = simulate_refused(tmp_path, "[" * 5000 + "\n", capsys)
    assert err == (f"error: {tmp_path / 'scene.yaml'}: invalid YAML: lists or mappings nested too deeply "
                   "(hundreds of levels)")


def test_json_nested_thousands_deep_is_one_error(tmp_path: Path) -> None:
    from fracture_gs.data import DatasetError
    from fracture_gs.data.files import read_json
    from fracture_gs.render.views import ViewSpecError, cameras_from_json

    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)
    with pytest.raises(DatasetError, match="nested too deeply"):
        read_json(str(deep))
    with pytest.raises(ViewSpecError, match="not a readable JSON file"):
        cameras_from_json(deep)


# ----------------------------------------------------------------------------- substeps (finding 14)


def test_a_substep_count_that_would_be_absurd_is_refused_before_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """E 1e13 Pa over 0.01 kg/m³ (both inside their bounds): a P-wave speed of 3.3e7 m/s, a
    substep of 5.6e-10 s, 1.8e9 substeps for 100 frames of 0.01 s."""
    scene = brittle_sphere(E=1.0e13, density=0.01)
    scene["frames"] = 100
    err = simulate_refused(tmp_path, scene, capsys)
    assert err.startswith("error: objects[0].materials[0]: E 1e+13 Pa, nu 0.2 and density 0.01 kg/m³ give a "
                          "P-wave speed of 3.33e+07 m/s and a substep of 5.62e-10 s")
    assert "would take 1.78e+09 substeps, more than 1e+08" in err


def test_the_density_of_the_hanging_run_is_out_of_range(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    err = simulate_refused(tmp_path, brittle_sphere(density=1.0e-300), capsys)
    assert err == "error: objects[0].materials[0].density: 1e-300 is not within [0.01, 100000]"


def test_the_substep_estimate_names_frames_or_the_speed() -> None:
    long_run = brittle_sphere()
    long_run.update(frames=1_000_000, frame_dt=1.0)
    config = parse_scene(long_run)
    built = build_scene(config, torch.device("cpu"))
    with pytest.raises(SceneError, match=r"^frames: 1000000 frames is too long a run"):
        check_substeps(config, built)
    fast = brittle_sphere(E=1.0e4)
    fast.update(frames=1000, frame_dt=1.0, gravity=[0, 0, 0])
    fast["objects"][0]["velocity"] = [1.0e4, 0, 0]
    config = parse_scene(fast)
    built = build_scene(config, torch.device("cpu"))
    with pytest.raises(SceneError, match=r"^objects\[0\]: its initial speed of 1e\+04 m/s"):
        check_substeps(config, built)
    ordinary = parse_scene(brittle_sphere())
    built = build_scene(ordinary, torch.device("cpu"))
    check_substeps(ordinary, built)
    solver = create_solver(built, torch.device("cpu"), "reference")
    assert estimate_substeps(ordinary, built).dt == pytest.approx(solver.stable_dt(), rel=1e-6)


# ----------------------------------------------------------------------------- a full disk (finding 15)


def test_a_failed_atomic_write_names_its_file_and_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "frame_00003.npz"
    with pytest.raises(OSError) as caught:
        atomic_write(target, disk_full)
    assert os_error_line(caught.value) == f"{target}: No space left on device"
    assert list(tmp_path.iterdir()) == []


def test_simulate_on_a_full_disk_exits_1_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(brittle_sphere()))
    out = tmp_path / "sim"
    monkeypatch.setattr(os, "fsync", disk_full)
    assert simulate_cli.main(["--scene", str(scene), "--out", str(out), "--device", "cpu"]) == 1
    err = one_error_line(capsys)
    assert err.startswith(f"error: {out}{os.sep}") and err.endswith(": No space left on device"), err


def test_train_on_a_full_disk_exits_1_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "model"
    monkeypatch.setattr(os, "fsync", disk_full)
    assert train_main(["-s", str(TRAIN_FIXTURE), "-m", str(model), "--sdf-res", "16", "--sdf-iters", "0",
                       "--iterations", "1", "--n-surface", "50", "--nv", "0", "--quiet"]) == 1
    err = one_error_line(capsys)
    assert err.startswith(f"error: {model}{os.sep}") and err.endswith(": No space left on device"), err


def test_the_generator_on_a_full_disk_exits_1_naming_the_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from PIL import Image

    monkeypatch.setattr(generator, "require_mitsuba", lambda: None)
    monkeypatch.setattr(generator, "build_scene", lambda obj: None)
    monkeypatch.setattr(generator, "render_view", lambda *args, **kwargs: np.zeros((8, 8, 4)))
    monkeypatch.setattr(Image.Image, "save", disk_full)
    out = tmp_path / "bowl"
    assert synthetic_cli.main(["--object", "bowl", "--out", str(out), "--width", "8", "--height", "8",
                               "--n-train", "1", "--n-test", "0", "--grid", "16", "--quiet"]) == 1
    partial = generator.partial_folder(str(out))
    assert one_error_line(capsys) == f"error: {partial}/train/r_0.png: No space left on device"
    assert list(tmp_path.iterdir()) == []


def test_render_on_a_full_disk_exits_1_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    sim = small_simulation(tmp_path)
    monkeypatch.setattr(os, "fsync", disk_full)
    assert render_cli.main(["--sim", str(sim), "--views", "orbit:1", "--resolution", "16", "16"]) == 1
    err = one_error_line(capsys)
    assert err.startswith(f"error: {sim / 'renders'}{os.sep}") and err.endswith(": No space left on device")
    assert not list(sim.rglob("*.tmp*"))


def test_a_stopped_video_encoder_is_one_line_naming_the_video(tmp_path: Path) -> None:
    writer = video.Mp4Writer(tmp_path / "video.mp4", 16, 16, 30.0)

    class Stopped:
        def send(self, frame: Any) -> None:
            raise OSError("[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\nffmpeg -y ...\n\nFFMPEG STDERR OUTPUT:\n")

        def close(self) -> None:
            raise OSError("broken pipe")

    running, writer._writer = writer._writer, Stopped()
    with pytest.raises(OSError) as caught:
        writer.write(np.zeros((16, 16, 3), np.uint8))
    assert os_error_line(caught.value) == (f"{tmp_path / 'video.mp4'}: the video encoder ffmpeg stopped "
                                           "([Errno 32] Broken pipe)")
    running.close()
    writer.abort()
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- brittle numbers (finding 16)


@pytest.mark.parametrize("key, value, problem", [
    ("weibull_m", 0.01, "0.01 is not within [1, 100] (nor exactly 0)"),
    ("strength", 1e300, "1e+300 is not within [1, 1e+11]"),
    ("fracture_energy", 1e300, "1e+300 is not within [0, 1e+07]"),
])
def test_brittle_numbers_out_of_range_are_refused(key: str, value: float, problem: str) -> None:
    assert refusal(brittle_sphere(**{key: value})) == f"objects[0].materials[0].{key}: {problem}"


def test_weibull_strengths_at_the_bounds_are_finite_without_warnings() -> None:
    """The strongest particle: σ_F (V_ref ln R / (V ln 0.5))^(1/m) with R at its smallest
    (2^-54, ln R / ln 0.5 = 54) at m = 1 and the largest strength is 54 V_ref / V σ_F: finite
    in float32 for volumes a thousand times below the mean."""
    material = BrittleMaterial(E=1.0e13, nu=0.2, density=1.0e5, strength=bounds.STRESS[1],
                               fracture_energy=FRACTURE_ENERGY_RANGE[1], weibull_m=WEIBULL_M_RANGE[0])
    count = 100_000
    volume = torch.from_numpy(np.where(np.arange(count) % 2 == 0, 1.0e-9, 1.0e-6).astype(np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        strengths = particle_strengths([material], torch.zeros(count, dtype=torch.int32), volume, seed=7)
    assert strengths is not None and bool(torch.isfinite(strengths).all())
    assert float(strengths.max()) <= 54.0 * 500.0 * bounds.STRESS[1]


def test_the_smallest_weibull_modulus_breaks_nothing_in_free_flight() -> None:
    """weibull_m 0.01 made half a sphere 'fractured' in free flight (221 of these 458 particles
    within 0.04 s); at the smallest modulus allowed, 1, a sphere in free fall stays whole."""
    config = parse_scene(brittle_sphere(E=2.0e4, strength=200.0, weibull_m=WEIBULL_M_RANGE[0]))
    built = build_scene(config, torch.device("cpu"))
    solver = create_solver(built, torch.device("cpu"), "auto")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(4):
            solver.advance(0.01)
    assert solver.diagnostics()["fractured"] == 0


# ----------------------------------------------------------------------------- speeds, moduli, gravity (finding 17)


@pytest.mark.parametrize("where, value, key, problem", [
    ("velocity", [1e8, 0, 0], "objects[0].velocity[0]", "1e+08 is not within [-10000, 10000]"),
    ("velocity", [0, 0, -1e300], "objects[0].velocity[2]", "-1e+300 is not within [-10000, 10000]"),
    ("angular_velocity", [0, 1e300, 0], "objects[0].angular_velocity[1]", "1e+300 is not within [-10000, 10000]"),
    ("velocity_gradient", [[0, 0, 0], [0, 1e300, 0], [0, 0, 0]], "objects[0].velocity_gradient[1][1]",
     "1e+300 is not within [-10000, 10000]"),
    ("gravity", [0, 0, -1e300], "gravity[2]", "-1e+300 is not within [-10000, 10000]"),
    ("E", 1e300, "objects[0].materials[0].E", "1e+300 is not within [1, 1e+13]"),
    ("density", 1e300, "objects[0].materials[0].density", "1e+300 is not within [0.01, 100000]"),
    ("softening", 1e300, "objects[0].materials[0].softening", "1e+300 is not within [1, 1e+06]"),
])
def test_speeds_moduli_gravity_and_softening_out_of_range_are_refused(where: str, value: Any, key: str,
                                                                      problem: str) -> None:
    scene = brittle_sphere()
    if where == "gravity":
        scene["gravity"] = value
    elif where in ("E", "density"):
        scene["objects"][0]["materials"][0][where] = value
    elif where == "softening":
        scene["objects"][0]["materials"] = [{"part": 0, "preset": "porcelain", "softening": value}]
    else:
        scene["objects"][0][where] = value
    assert refusal(scene) == f"{key}: {problem}"


def test_simulate_frames_option_has_the_scene_keys_range(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(brittle_sphere()))
    out = tmp_path / "sim"
    assert simulate_cli.main(["--scene", str(scene), "--out", str(out), "--frames", "1000001"]) == 2
    assert one_error_line(capsys) == "error: --frames: 1000001 is not <= 1000000"
    assert not out.exists()


def test_a_velocity_out_of_range_stops_simulate_with_one_line(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    scene = brittle_sphere()
    scene["objects"][0]["velocity"] = [1e8, 0, 0]
    assert simulate_refused(tmp_path, scene, capsys) == \
        "error: objects[0].velocity[0]: 1e+08 is not within [-10000, 10000]"


# ----------------------------------------------------------------------------- a file name as the name (finding 18)


def test_a_scene_file_whose_name_is_not_a_valid_name_says_what_to_do(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = brittle_sphere()
    del scene["name"]
    err = simulate_refused(tmp_path, scene, capsys, name="my scene.yaml")
    assert err == (f"error: {tmp_path / 'my scene.yaml'}: the scene has no 'name' key and its file name "
                   "'my scene' is not a valid name (letters, digits, '_', '-', '.'; no spaces or slashes); "
                   "add a 'name:' line to the scene or rename the file")
    (tmp_path / "my_scene.yaml").write_text(yaml.safe_dump(scene))
    assert load_scene(tmp_path / "my_scene.yaml").name == "my_scene"


# ----------------------------------------------------------------------------- the generator's seed, evaluate's table (finding 19)


def test_the_generator_names_its_seed_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "teapot"
    assert synthetic_cli.main(["--object", "teapot", "--out", str(out), "--seed", "-1", "--quiet"]) == 2
    assert one_error_line(capsys) == f"error: --seed: -1 is not within [0, {2 ** 64 - 1}]"
    assert not out.exists()


def test_every_generator_seed_gives_mitsuba_a_32_bit_seed() -> None:
    assert [generator.GeneratorSettings(seed=3).view_seed(n) for n in (0, 7)] == [300009, 300016]
    largest = generator.GeneratorSettings(seed=bounds.SEED_MAX)
    largest.validate()
    assert all(0 <= largest.view_seed(n) < 2 ** 32 for n in range(200))


def _run(label: str, psnr: float, lpips: Any, fid: Any) -> dict[str, Any]:
    return {"label": label, "window": {"note": ""},
            "metrics": {"psnr": {"mean": psnr}, "lpips": lpips, "fid": fid, "n_reference": 8, "n_window": 24}}


def test_evaluate_table_keeps_unavailable_metrics_apart() -> None:
    text = print_comparison({"runs": [_run("ours", 27.0512, "unavailable: expected lpips_alex.pth",
                                            "unavailable: expected inception.pth")]})
    assert text.splitlines() == ["run        PSNR        LPIPS          FID  N (ref/window)",
                                 "ours      27.05  unavailable  unavailable  8 / 24"]


def test_evaluate_table_of_available_metrics_is_unchanged() -> None:
    text = print_comparison({"runs": [_run("ours", 27.0512, {"mean": 0.2871}, 90.754),
                                      _run("baseline", 26.83, {"mean": 0.3}, math.inf)]})
    assert text.splitlines() == ["run            PSNR    LPIPS       FID  N (ref/window)",
                                 "ours          27.05    0.287     90.75  8 / 24",
                                 "baseline      26.83    0.300       inf  8 / 24"]
