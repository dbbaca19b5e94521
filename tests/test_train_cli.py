"""train.py end to end on the shipped fixture (5 views, 96x96), --from-ply, checkpoints and
every bad input; render.py -m on the result. Tiny settings: seconds, not minutes."""
from __future__ import annotations

import ast
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import plyfile
import pytest
import torch
import trimesh

from fracture_gs.cli import render_model
from fracture_gs.cli.train import main as train_main
from fracture_gs.gaussians import GaussianModel, read_ply, write_ply
from fracture_gs.gaussians.ply import ply_property_names
from fracture_gs.recon.hull import VisualHull
from fracture_gs.io.particles_ply import read_particles_ply
from fracture_gs.folders.model_folder import run_lock

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "synthetic_fixture"
TINY = ["--sdf-res", "24", "--sdf-iters", "16", "--iterations", "24", "--n-surface", "300",
        "--nv", "2", "--particle-res", "10", "--sdf-rays", "256", "--quiet"]


def _run(argv: list[str]) -> int:
    return train_main([str(a) for a in argv])


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    model = tmp_path_factory.mktemp("train") / "teapot"
    assert _run(["-s", FIXTURE, "-m", model, "--checkpoint_every", "10", *TINY]) == 0
    return model


def test_every_output_file_is_written_and_consistent(trained: Path) -> None:
    expected = {"cfg_args", "cameras.json", "input.ply", "sdf.npz", "mesh.ply", "particles.ply",
                "particles.json", "train_log.csv", "timings.json", "point_cloud"}
    assert expected <= set(os.listdir(trained))
    assert not [n for n in os.listdir(trained) if n.startswith(".tmp_") or n.endswith(".pth")]
    # cfg_args: a Namespace(...) repr like 3DGS writes
    text = (trained / "cfg_args").read_text()
    call = ast.parse(text, mode="eval").body
    assert call.func.id == "Namespace"
    options = {k.arg: ast.literal_eval(k.value) for k in call.keywords}
    assert options["sh_degree"] == 3 and options["source_path"] == str(FIXTURE)
    # the default preset's learning rates (raised over 3DGS's for the short schedule)
    assert (options["feature_lr"], options["opacity_lr"], options["scaling_lr"]) == (1e-2, 5e-2, 1e-2)
    # cameras.json: 3DGS entries, test views first, then train
    cameras = json.loads((trained / "cameras.json").read_text())
    assert len(cameras) == 6 and {"id", "img_name", "width", "height", "position", "rotation",
                                  "fx", "fy"} <= set(cameras[0])
    assert cameras[0]["width"] == 96 and np.asarray(cameras[1]["rotation"]).shape == (3, 3)
    # Gaussians in the standard layout, isotropic, one per surface particle
    ply = plyfile.PlyData.read(str(trained / "point_cloud" / "iteration_24" / "point_cloud.ply"))
    assert [p.name for p in ply["vertex"].properties] == ply_property_names(3)
    gaussians = read_ply(str(trained / "point_cloud" / "iteration_24" / "point_cloud.ply"),
                         isotropic=True)
    particles = read_particles_ply(str(trained / "particles.ply"))
    surface = particles["is_surface"] > 0
    assert surface.sum() == 300 == gaussians.num_gaussians
    assert (~surface).sum() > 0
    index = particles["gaussian_index"]
    assert np.array_equal(np.sort(index[surface]), np.arange(300))
    assert np.all(index[~surface] == -1)
    position = np.stack([particles[a] for a in "xyz"], axis=1)
    assert np.allclose(gaussians.means.detach().numpy()[index[surface]], position[surface],
                       atol=1e-6)
    assert np.all(particles["part_id"] == 0)
    assert np.all(particles["volume"] > 0)
    mesh = trimesh.load(str(trained / "mesh.ply"))
    assert particles["volume"].sum() == pytest.approx(mesh.volume, rel=1e-4)
    assert particles["comments"]["surface_spacing"] > 0
    info = json.loads((trained / "particles.json").read_text())
    assert info["n_surface"] == 300 and info["interior_particle_size"] > 0
    sdf = np.load(trained / "sdf.npz")
    assert sdf["sdf"].ndim == 3 and sdf["sdf"].shape == sdf["hull_sdf"].shape
    assert float(sdf["voxel"]) > 0 and sdf["origin"].shape == (3,)
    # log and timings
    log = (trained / "train_log.csv").read_text().splitlines()
    assert log[0].startswith("stage,iteration,loss") and any(l.startswith("gaussians") for l in log)
    summary = json.loads((trained / "timings.json").read_text())
    for stage in ("visual_hull", "stereo_carving", "sdf_refinement", "marching_cubes",
                  "particles", "gaussians", "total"):
        assert summary["timings"][stage]["wall_s"] >= 0 and "cpu_s" in summary["timings"][stage]
    assert summary["test"]["views"] == 1 and summary["train"]["views"] == 5
    # even tiny training improves on the grey start
    assert summary["train"]["psnr"] > 12


def test_particles_ply_loads_into_the_simulator(trained: Path) -> None:
    from fracture_gs.mpm.scene import load_particles_ply
    loaded = load_particles_ply(trained / "particles.ply")
    assert loaded.is_surface.sum() == 300
    assert np.all(loaded.rest_volume > 0)


def test_render_model_writes_3dgs_folders(trained: Path, capsys: pytest.CaptureFixture) -> None:
    assert render_model.main(["-m", str(trained), "--quiet"]) == 0
    for split, count in (("train", 5), ("test", 1)):
        for kind in ("renders", "gt"):
            folder = trained / split / "ours_24" / kind
            assert sorted(os.listdir(folder)) == [f"{i:05d}.png" for i in range(count)]
    image = cv2.imread(str(trained / "test" / "ours_24" / "renders" / "00000.png"))
    assert image.shape == (96, 96, 3) and image.max() > 0
    assert "PSNR" in capsys.readouterr().out
    shutil.rmtree(trained / "test")
    assert render_model.main(["-m", str(trained), "--skip_train", "--quiet"]) == 0
    assert (trained / "test").is_dir()
    assert render_model.main(["-m", str(trained / "missing")]) == 2


def test_interrupted_training_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    reference = tmp_path / "reference"
    assert _run(["-s", FIXTURE, "-m", reference, "--checkpoint_every", "10", *TINY]) == 0
    interrupted = tmp_path / "interrupted"
    from fracture_gs.recon import gaussian_fit
    original = gaussian_fit.render_model
    calls = {"count": 0}

    def failing(*args, **kwargs):
        calls["count"] += 1
        if calls["count"] == 15:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    with mock.patch.object(gaussian_fit, "render_model", failing):
        assert _run(["-s", FIXTURE, "-m", interrupted, "--checkpoint_every", "10", *TINY]) == 130
    assert (interrupted / "chkpnt10.pth").is_file()
    assert not (interrupted / "point_cloud").exists()
    assert _run(["-s", FIXTURE, "--start_checkpoint", interrupted / "chkpnt10.pth",
                 "--checkpoint_every", "10", *TINY]) == 0
    resumed = read_ply(str(interrupted / "point_cloud" / "iteration_24" / "point_cloud.ply"))
    straight = read_ply(str(reference / "point_cloud" / "iteration_24" / "point_cloud.ply"))
    for name, value in resumed.raw_tensors().items():
        assert torch.allclose(value, straight.raw_tensors()[name], atol=1e-6), name
    assert not list(interrupted.glob("chkpnt*.pth"))


def test_a_second_run_into_the_same_model_folder_is_refused(trained: Path,
                                                             capsys: pytest.CaptureFixture) -> None:
    """Two train.py runs writing one folder would mix their files: the second one stops with a
    one-line error (exit 2) and touches nothing; once the first ends, the folder is free."""
    before = {name: (trained / name).stat().st_mtime_ns for name in ("sdf.npz", "cfg_args")}
    with run_lock(str(trained)):   # another run holds the folder
        assert _run(["-s", FIXTURE, "-m", trained, *TINY]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another train.py run is writing this model folder" in err[0]
    assert {name: (trained / name).stat().st_mtime_ns for name in before} == before
    with run_lock(str(trained)):   # released by the refused run and by the holder
        pass


def test_from_sdf_reuses_the_geometry_of_an_earlier_run(trained: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    refit = tmp_path / "refit"
    assert _run(["-s", FIXTURE, "-m", refit, "--from-sdf", trained / "sdf.npz", *TINY]) == 0
    timings = json.loads((refit / "timings.json").read_text())
    assert "sdf_refinement" not in timings["timings"] and "visual_hull" not in timings["timings"]
    assert timings["from_sdf"] == str(trained / "sdf.npz")
    before = trimesh.load(str(trained / "mesh.ply"), process=False)
    after = trimesh.load(str(refit / "mesh.ply"), process=False)
    assert np.array_equal(before.vertices, after.vertices)
    assert timings["hull_volume"] == pytest.approx(
        json.loads((trained / "timings.json").read_text())["hull_volume"])
    broken = tmp_path / "broken.npz"
    np.savez(broken, sdf=np.zeros((4, 4)))
    out = tmp_path / "out"
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--from-sdf", broken, *TINY], out,
                        "--from-sdf", str(broken), "not an sdf.npz")


def _original_3dgs_ply(path: Path, points: np.ndarray, seed: int = 0) -> GaussianModel:
    """Anisotropic SH-3 Gaussians as the original 3DGS writes them."""
    generator = torch.Generator().manual_seed(seed)
    count = len(points)
    model = GaussianModel(torch.from_numpy(points).float(),
                          torch.randn(count, 1, 3, generator=generator),
                          0.1 * torch.randn(count, 15, 3, generator=generator),
                          torch.full((count, 1), 3.0),
                          torch.log(torch.tensor([0.03, 0.03, 0.006])).repeat(count, 1)
                          + 0.1 * torch.randn(count, 3, generator=generator),
                          torch.randn(count, 4, generator=generator))
    write_ply(str(path), model)
    return model


def test_from_ply_binds_particles_to_the_nearest_gaussian(tmp_path: Path) -> None:
    mesh = trimesh.load(str(FIXTURE / "gt_mesh.ply"))
    points, _ = trimesh.sample.sample_surface(mesh, 2000, seed=3)
    source = tmp_path / "iteration_7000" / "point_cloud.ply"
    imported = _original_3dgs_ply(source, np.asarray(points))
    model = tmp_path / "model"
    assert _run(["-s", FIXTURE, "-m", model, "--from-ply", source, *TINY]) == 0
    written = read_ply(str(model / "point_cloud" / "iteration_7000" / "point_cloud.ply"))
    for name, value in written.raw_tensors().items():
        assert torch.equal(value, imported.raw_tensors()[name]), name
    particles = read_particles_ply(str(model / "particles.ply"))
    surface = particles["is_surface"] > 0
    position = np.stack([particles[a] for a in "xyz"], axis=1)[surface]
    means = imported.means.detach().numpy()
    brute = np.argmin(((position[:, None, :] - means[None]) ** 2).sum(-1), axis=1)
    assert np.array_equal(particles["gaussian_index"][surface], brute)
    summary = json.loads((model / "timings.json").read_text())
    assert summary["unbound_gaussians"] == 2000 - len(np.unique(brute))


def test_from_ply_warns_about_unbound_gaussians_and_records_their_sh_degree(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """3,000 SH-0 Gaussians for 300 surface particles: 2,700 or more are carried by no particle,
    which the console says with the count and the reason; cfg_args records SH degree 0."""
    mesh = trimesh.load(str(FIXTURE / "gt_mesh.ply"))
    points, _ = trimesh.sample.sample_surface(mesh, 3000, seed=5)
    count = len(points)
    generator = torch.Generator().manual_seed(5)
    imported = GaussianModel(torch.from_numpy(np.asarray(points)).float(),
                             torch.randn(count, 1, 3, generator=generator),
                             torch.zeros(count, 0, 3), torch.full((count, 1), 3.0),
                             torch.full((count, 3), math.log(0.01)),
                             torch.randn(count, 4, generator=generator))
    assert imported.sh_degree == 0
    source = tmp_path / "point_cloud.ply"
    write_ply(str(source), imported)
    model = tmp_path / "model"
    assert _run(["-s", FIXTURE, "-m", model, "--from-ply", source, *TINY]) == 0
    summary = json.loads((model / "timings.json").read_text())
    unbound = summary["unbound_gaussians"]
    assert unbound >= count - 300
    warnings = [line for line in capsys.readouterr().err.splitlines()
                if line.startswith("warning: ")]
    assert len(warnings) == 1, warnings
    assert f"{unbound} of {count} imported Gaussians" in warnings[0]
    assert "will not be drawn" in warnings[0] and "--n-surface" in warnings[0]
    options = ast.parse((model / "cfg_args").read_text(), mode="eval").body.keywords
    assert {k.arg: ast.literal_eval(k.value) for k in options}["sh_degree"] == 0
    assert read_ply(str(model / "point_cloud" / "iteration_0" / "point_cloud.ply")).sh_degree == 0


def test_unbound_warning_reasons() -> None:
    from fracture_gs.recon.imported import unbound_warning

    assert unbound_warning(np.array([2, 0, 1, 2]), 3) is None        # every Gaussian carried
    few = unbound_warning(np.array([4, 0]), 5)
    assert few is not None and few.startswith("--from-ply: 3 of 5 imported Gaussians")
    assert "only 2 surface particles" in few and "--n-surface" in few
    shared = unbound_warning(np.array([0, 0, 1, 1, 2, 2]), 4)
    assert shared is not None and "1 of 4" in shared and "nearest Gaussian of no surface" in shared


def test_unusable_from_sdf_and_from_ply_files_give_one_line_and_leave_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--from-sdf", empty, *TINY], out,
                        "--from-sdf", str(empty), "empty")
    grid = np.zeros((8, 8, 8), np.float32)
    np.savez(tmp_path / "whole.npz", sdf=grid, hull_sdf=grid, origin=np.zeros(3), voxel=0.1)
    truncated = tmp_path / "truncated.npz"
    whole = (tmp_path / "whole.npz").read_bytes()
    truncated.write_bytes(whole[:len(whole) // 2])
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--from-sdf", truncated, *TINY], out,
                        "--from-sdf", str(truncated), "not an sdf.npz")
    no_vertices = tmp_path / "no_vertices.ply"
    columns = np.zeros(0, dtype=[(name, "f4") for name in ply_property_names(3)])
    plyfile.PlyData([plyfile.PlyElement.describe(columns, "vertex")]).write(str(no_vertices))
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--from-ply", no_vertices, *TINY],
                        out, str(no_vertices), "no Gaussians")


def _fixture_copy(tmp_path: Path, name: str = "data") -> Path:
    copy = tmp_path / name
    shutil.copytree(FIXTURE, copy)
    return copy


def _strip_alpha(folder: Path) -> None:
    for path in folder.glob("*/*.png"):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), image[:, :, :3])


def test_without_masks_the_opacity_field_route_works(tmp_path: Path) -> None:
    data = _fixture_copy(tmp_path)
    _strip_alpha(data)
    mesh = trimesh.load(str(FIXTURE / "gt_mesh.ply"))
    points, _ = trimesh.sample.sample_surface(mesh, 6000, seed=4)
    source = tmp_path / "point_cloud.ply"
    _original_3dgs_ply(source, np.asarray(points))
    lower, upper = mesh.bounds[0] - 0.1, mesh.bounds[1] + 0.1
    model = tmp_path / "model"
    assert _run(["-s", data, "-m", model, "--from-ply", source, "--bbox", *lower, *upper,
                 *TINY]) == 0
    ours = trimesh.load(str(model / "mesh.ply"))
    assert ours.volume == pytest.approx(mesh.volume, rel=0.35)


def _expect_input_error(capsys: pytest.CaptureFixture, argv: list, output: Path,
                        *fragments: str) -> str:
    assert _run(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in err, err
    assert not output.exists(), "a failed run left files behind"
    return err


def test_bad_inputs_give_one_line_and_leave_nothing(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    _expect_input_error(capsys, ["-s", tmp_path / "nowhere", "-m", out, *TINY], out,
                        "nowhere", "not found")
    no_alpha = _fixture_copy(tmp_path, "no_alpha")
    _strip_alpha(no_alpha)
    _expect_input_error(capsys, ["-s", no_alpha, "-m", out, *TINY], out, "masks/", "--bbox")
    mismatch = _fixture_copy(tmp_path, "mismatch")
    image = cv2.imread(str(mismatch / "train" / "r_3.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(mismatch / "train" / "r_3.png"), cv2.resize(image, (80, 80)))
    _expect_input_error(capsys, ["-s", mismatch, "-m", out, *TINY], out, "r_3.png", "80x80")
    missing = _fixture_copy(tmp_path, "missing")
    (missing / "train" / "r_2.png").unlink()
    _expect_input_error(capsys, ["-s", missing, "-m", out, *TINY], out, "r_2", "not found")
    parts = tmp_path / "parts.json"
    parts.write_text(json.dumps({"format": "fracture_gs/parts-v1",
                                 "parts": [{"id": 0, "name": "body"}, {"id": 1, "name": "lid"}],
                                 "default_part": 0,
                                 "rules": [{"part": 1, "box": {"min": [5, 5, 5],
                                                               "max": [6, 6, 6]}}]}))
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--parts", parts, *TINY], out,
                        str(parts), "part 1 ('lid') contains no particle")
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, *TINY, "--nv", "-1"], out, "--nv")
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, *TINY, "--opacity_lr", "0"], out,
                        "--opacity_lr", "must be > 0")


def test_an_empty_mesh_names_the_threshold_and_what_to_try(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture
                                                           ) -> None:
    from fracture_gs.recon import pipeline
    real = pipeline.visual_hull

    def empty_hull(*args, **kwargs) -> VisualHull:
        hull = real(*args, **kwargs)
        return VisualHull(hull.grid, hull.sdf.abs() + 0.01)   # nothing inside

    out = tmp_path / "out"
    with mock.patch.object(pipeline, "visual_hull", empty_hull):
        _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, "--sdf-iters", "0", *TINY[4:]],
                            out, "marching cubes at level 0", "--sdf-res")


def test_exit_status_and_message_of_the_script(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, str(ROOT / "train.py"), "-s",
                             str(tmp_path / "nowhere"), "-m", str(tmp_path / "out")],
                            capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'nowhere'}: dataset folder not found"]


def test_presets_set_the_learning_rates_and_flags_override_them() -> None:
    from fracture_gs.cli.train import build_parser, config_from_args
    parser = build_parser()
    default = config_from_args(parser.parse_args(["-s", "data/x"]))
    paper = config_from_args(parser.parse_args(["-s", "data/x", "--preset", "paper"]))
    given = config_from_args(parser.parse_args(["-s", "data/x", "--preset", "paper", "--feature_lr", "0.02"]))
    assert (default.feature_lr, default.opacity_lr, default.scaling_lr) == (1e-2, 5e-2, 1e-2)
    assert (paper.feature_lr, paper.opacity_lr, paper.scaling_lr) == (2.5e-3, 2.5e-2, 5e-3)  # 3DGS
    assert given.feature_lr == 0.02 and given.opacity_lr == 2.5e-2


def test_hold_out_and_up_flags_are_checked(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, *TINY, "--holdout-every", "1"], out,
                        "--holdout-every", "must be 0 (no test split) or >= 2")
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, *TINY, "--holdout-every", "8"], out,
                        "own test split")
    _expect_input_error(capsys, ["-s", FIXTURE, "-m", out, *TINY, "--up", "0", "0", "0"], out,
                        "--up", "non-zero direction")


def test_the_run_records_where_the_object_lies_and_leaves_no_lock(trained: Path) -> None:
    """object.json: the box of the particles and the up of the fixture's level cameras (+z, the
    Blender world's); the lock file is gone once the run ended."""
    from fracture_gs.io.object_frame import read_object_frame

    frame = read_object_frame(trained / "object.json")
    particles = read_particles_ply(str(trained / "particles.ply"))
    position = np.stack([particles[a] for a in "xyz"], axis=1)
    assert np.allclose(frame.bbox_min, position.min(axis=0), atol=1e-6)
    assert np.allclose(frame.bbox_max, position.max(axis=0), atol=1e-6)
    assert np.allclose(frame.up, [0, 0, 1], atol=1e-6) and frame.up_source.startswith("level")
    assert frame.height == pytest.approx(float(np.ptp(position[:, 2])), rel=1e-6)
    assert not (trained / ".train.lock").exists()
    assert "underside_cut" not in json.loads((trained / "timings.json").read_text())
