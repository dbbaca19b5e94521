"""view.py without a browser: splat conversion, the frame cache, the sources (same code path
as render.py), bad input (the same one-line errors as render.py, port taken), and the lifetime:
a real websocket client that leaves ends the viewer after the grace period, stop() leaves no
thread behind, Ctrl-C (SIGINT) ends the process cleanly."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import CancelledError
from pathlib import Path

import numpy as np
import pytest
import torch

from fracture_gs.cli import render as render_cli
from fracture_gs.cli import view as view_cli
from fracture_gs.render.frame_gaussians import FrameGaussians, SceneGaussians
from fracture_gs.render.sh import SH_C0
from fracture_gs.folders.sim_reader import Simulation
from fracture_gs.viewer.app import PortInUseError, Viewer, ViewerOptions, check_port_free
from fracture_gs.testing.headless_browser import WebsocketProbe, wait_for
from fracture_gs.viewer.cache import FrameCache
from fracture_gs.viewer.sources import ModelSource, SimulationSource
from fracture_gs.viewer.splats import (DAMAGE_PALETTE, HIGHLIGHT_RGB, PIECE_PALETTE, SMALL_PIECE_RGB, ObjectSplats,
                                      object_splats, to_uint8, unit_scale_for)
from render_scenes import block_scene, identity_frames, lattice_block, write_model, write_sim

REPO = Path(__file__).resolve().parents[1]
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def block_sim(tmp_path_factory) -> Path:
    """A trained-model block (SH degree 1) whose frame 1 is sheared and half fractured."""
    root = tmp_path_factory.mktemp("viewer")
    points, surface = lattice_block((0.08, 0.06, 0.05))
    write_model(root / "model", points, surface)
    transform = {"scale": 1.0, "translate": [0.5, 0.5, 0.5]}
    rest = points + 0.5
    frames = identity_frames(rest, 2)
    shear = np.eye(3, dtype=np.float32)
    shear[0, 2] = 0.3
    frames[1]["F_E"] = np.tile(shear, (rest.shape[0], 1, 1))
    frames[1]["x"] = (rest + [0.05, 0.0, 0.0]).astype(np.float32)
    frames[1]["fractured"] = rest[:, 0] > 0.5
    gaussian_index = np.full(rest.shape[0], -1, np.int64)
    gaussian_index[surface] = np.arange(int(surface.sum()))
    particles = {"rest_x": rest.astype(np.float32), "obj_id": np.zeros(rest.shape[0], np.int32),
                 "is_surface": surface, "gaussian_index": gaussian_index,
                 "rest_volume": np.full(rest.shape[0], 0.02 ** 3, np.float32)}
    return write_sim(root / "sim", block_scene(root / "model", transform), particles, frames)


def _gaussians(count: int, objects: np.ndarray) -> FrameGaussians:
    generator = torch.Generator().manual_seed(0)
    factors = torch.randn(count, 3, 3, generator=generator) * 0.01
    return FrameGaussians(
        means=torch.rand(count, 3, generator=generator),
        covariances=factors @ factors.transpose(1, 2) + 1e-6 * torch.eye(3),
        opacities=torch.rand(count, generator=generator),
        sh=torch.randn(count, 4, 3, generator=generator),
        view_rotations=torch.eye(3).expand(count, 3, 3),
        exclusive=torch.full((count,), -1, dtype=torch.int64),
        object_id=torch.as_tensor(objects, dtype=torch.int32),
        is_fpgo=torch.arange(count) == count - 1,
        particle=torch.arange(count, dtype=torch.int64) % 5)


def test_splats_are_split_by_object_in_viewer_units_with_dc_colour():
    objects = np.array([1, 0, 1, 1, 0, 1])
    gaussians = _gaussians(6, objects)
    scale = unit_scale_for(np.zeros(3), np.array([0.0, 0.3, 0.4]))
    assert scale == pytest.approx(100.0 / 0.5)
    fractured_particles = torch.tensor([False, False, False, True, False])
    splats = object_splats(gaussians, 3, scale, fractured_particles)
    assert [len(s) for s in splats] == [2, 4, 0]
    rows = np.nonzero(objects == 1)[0]
    one = splats[1]
    np.testing.assert_allclose(one.centers, gaussians.means[rows].numpy() * scale, rtol=1e-6)
    np.testing.assert_allclose(one.covariances, gaussians.covariances[rows].numpy() * scale ** 2,
                               rtol=1e-3, atol=1e-3 * scale ** 2 * 1e-4)   # float16
    expected_rgb = np.clip(SH_C0 * gaussians.sh[rows, 0].numpy() + 0.5, 0.0, 1.0)
    np.testing.assert_allclose(one.rgba[:, :3] / 255.0, expected_rgb, atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(one.rgba[:, 3] / 255.0, gaussians.opacities[rows].numpy(),
                               atol=0.5 / 255 + 1e-6)
    # Gaussian 3 follows fractured particle 3; Gaussian 5 is FPGO's own (is_fpgo)
    np.testing.assert_array_equal(one.fractured, [False, False, True, True])
    highlighted = ObjectSplats(one.packed(highlight_fractured=True), one.fractured)
    np.testing.assert_array_equal(highlighted.rgba[2:, :3], np.tile(to_uint8(np.asarray(HIGHLIGHT_RGB)), (2, 1)))
    np.testing.assert_array_equal(highlighted.rgba[:2], one.rgba[:2])
    np.testing.assert_array_equal(highlighted.rgba[:, 3], one.rgba[:, 3])
    np.testing.assert_array_equal(highlighted.centers, one.centers)
    assert one.packed(highlight_fractured=False) is one.buffer


def test_piece_colours_follow_the_particles_fragment_rank():
    objects = np.array([1, 0, 1, 1, 0, 1])
    gaussians = _gaussians(6, objects)            # Gaussian i follows particle i % 5
    ranks = torch.tensor([1, 0, -1, 0, 2])        # per particle (piece_ranks)
    fractured = torch.tensor([False, False, False, True, False])
    splats = object_splats(gaussians, 2, 10.0, fractured, ranks)
    one = splats[1]                               # Gaussians 0, 2, 3, 5 -> particles 0, 2, 3, 0
    np.testing.assert_array_equal(one.piece_rank, [1, -1, 0, 1])
    coloured = ObjectSplats(one.packed(False, colour_pieces=True), one.fractured)
    expected = np.stack([PIECE_PALETTE[1], SMALL_PIECE_RGB, PIECE_PALETTE[0], PIECE_PALETTE[1]])
    np.testing.assert_array_equal(coloured.rgba[:, :3], to_uint8(expected))
    np.testing.assert_array_equal(coloured.rgba[:, 3], one.rgba[:, 3])      # opacity kept
    both = ObjectSplats(one.packed(True, colour_pieces=True), one.fractured)  # highlight on top
    np.testing.assert_array_equal(both.rgba[2:, :3], np.tile(to_uint8(np.asarray(HIGHLIGHT_RGB)), (2, 1)))
    np.testing.assert_array_equal(both.rgba[:2, :3], coloured.rgba[:2, :3])
    plain = object_splats(gaussians, 2, 10.0, fractured)[1]   # no fragment ids: nothing to colour
    assert plain.piece_rank is None and plain.packed(False, colour_pieces=True) is plain.buffer


def test_damage_colours_follow_the_particles_damage():
    objects = np.array([0, 0, 0, 0, 0])
    gaussians = _gaussians(5, objects)            # Gaussian i follows particle i
    damage = torch.tensor([0.0, 0.25, 0.5, 1.0, 1.0])
    one = object_splats(gaussians, 1, 10.0, None, None, damage)[0]
    np.testing.assert_array_equal(one.damage, damage.numpy())
    coloured = ObjectSplats(one.packed(False, colour_damage=True), one.fractured)
    expected = DAMAGE_PALETTE[[0, 64, 128, 255, 255]]
    np.testing.assert_array_equal(coloured.rgba[:, :3], to_uint8(expected))
    np.testing.assert_array_equal(coloured.rgba[:, 3], one.rgba[:, 3])      # opacity kept
    assert tuple(coloured.rgba[0, :3]) != tuple(coloured.rgba[3, :3])       # intact and cracked differ
    plain = object_splats(gaussians, 1, 10.0)[0]   # no damage: nothing to colour
    assert plain.damage is None and plain.packed(False, colour_damage=True) is plain.buffer


def test_colour_by_damage_in_the_gui(block_sim: Path, tmp_path: Path):
    """A brittle run's frames carry damage: the GUI offers the checkbox and sends damage colours."""
    import yaml
    sim = tmp_path / "sim"
    shutil.copytree(block_sim, sim)
    scene = yaml.safe_load((sim / "scene.yaml").read_text())
    scene["objects"][0]["materials"] = [{"part": 0, "model": "brittle", "E": 1e6, "nu": 0.2, "density": 10.0,
                                         "strength": 1e4, "fracture_energy": 1.0}]
    (sim / "scene.yaml").write_text(yaml.safe_dump(scene, sort_keys=False))
    frame_file = sim / "frames" / "frame_00001.npz"
    with np.load(frame_file) as data:
        arrays = dict(data)
    damage = np.where(arrays["x"][:, 0] < np.median(arrays["x"][:, 0]), 0.0, 1.0).astype(np.float32)
    np.savez(frame_file, **arrays, damage=damage)
    source = SimulationSource(sim, CPU)
    assert source.has_damage and not SimulationSource(block_sim, CPU).has_damage
    prepared = source.prepare(1, False)
    assert set(np.unique(prepared.objects[0].damage)) <= {0.0, 1.0}
    assert colours_sent_with(source, "damage", (1, False, False, False, True)) == {
        tuple(to_uint8(DAMAGE_PALETTE[0])), tuple(to_uint8(DAMAGE_PALETTE[255]))}


def colours_sent_with(source: SimulationSource, checkbox: str, shown: tuple) -> set[tuple[int, ...]]:
    """The RGB colours the viewer sends for frame 1 once the GUI checkbox ``checkbox`` is ticked."""
    prepared = source.prepare(1, False)
    viewer = Viewer(source, ViewerOptions(port=0, start_frame=1, fpgo=False))
    viewer.start()
    try:
        assert viewer.wait_until_shown(1, timeout=30) and viewer.gui[checkbox].visible
        viewer.gui[checkbox].value = True
        assert wait_for(lambda: viewer.shown == shown, 30)
        sent = ObjectSplats(np.asarray(viewer._nodes[0].buffer), prepared.objects[0].fractured)
        return {tuple(rgb) for rgb in sent.rgba[:, :3]}
    finally:
        viewer.stop()


def test_colour_by_piece_in_the_gui(block_sim: Path, tmp_path: Path):
    sim = tmp_path / "sim"
    shutil.copytree(block_sim, sim)
    frame_file = sim / "frames" / "frame_00001.npz"
    with np.load(frame_file) as data:
        arrays = dict(data)
    rest = arrays["x"]
    left = rest[:, 0] < np.median(rest[:, 0])
    labels = np.where(left, 0, int(np.flatnonzero(~left)[0])).astype(np.int32)  # two halves
    np.savez(frame_file, **arrays, fragment_id=labels)
    source = SimulationSource(sim, CPU)
    assert source.has_pieces and not SimulationSource(block_sim, CPU).has_pieces
    prepared = source.prepare(1, False)
    assert set(np.unique(prepared.objects[0].piece_rank)) == {0, 1}
    assert source.prepare(0, False).objects[0].piece_rank is None   # frame 0 has no fragment_id
    assert colours_sent_with(source, "pieces", (1, False, False, True, False)) == {
        tuple(to_uint8(PIECE_PALETTE[0])), tuple(to_uint8(PIECE_PALETTE[1]))}


def test_packing_is_visers_own_layout():
    """The buffer we assign to a splat node equals what viser packs from the same arrays."""
    import viser

    splats = object_splats(_gaussians(7, np.zeros(7)), 1, 50.0)[0]
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        rgba = splats.rgba
        node = server.scene.add_gaussian_splats("/check", centers=splats.centers,
                                                covariances=splats.covariances,
                                                rgbs=rgba[:, :3], opacities=rgba[:, 3:])
        np.testing.assert_array_equal(np.asarray(node.buffer), splats.buffer)
    finally:
        server.stop()


def test_float16_covariances_keep_small_gaussians():
    """viser sends covariances as float16: millimetre Gaussians survive only in viewer units."""
    sigma = 0.0005     # half a millimetre in a metre-sized scene
    covariance = np.diag([sigma ** 2, (2 * sigma) ** 2, sigma ** 2]).astype(np.float32)
    covariance[0, 1] = covariance[1, 0] = 0.5 * sigma * 2 * sigma
    scale = unit_scale_for(np.zeros(3), np.ones(3))
    sent = (covariance * scale ** 2).astype(np.float16).astype(np.float32) / scale ** 2
    np.testing.assert_allclose(sent, covariance, rtol=2e-3, atol=1e-9)
    raw = covariance.astype(np.float16).astype(np.float32)
    assert np.abs(raw - covariance).max() / sigma ** 2 > 5e-2   # why the scaling exists


def test_frame_cache_prepares_in_background_and_evicts_least_recent():
    calls: list[tuple[int, str]] = []
    gate = threading.Event()

    def prepare(frame: int) -> int:
        gate.wait(5)
        calls.append((frame, threading.current_thread().name))
        if frame == 99:
            raise ValueError("broken frame")
        return frame * 10

    cache = FrameCache(prepare, capacity=2)
    try:
        first = cache.request((1,))
        assert cache.request((1,)) is first               # asked twice, prepared once
        gate.set()
        assert first.result(5) == 10
        assert cache.cached((1,))
        assert cache.request((2,)).result(5) == 20
        cache.request((1,))                               # 1 becomes the most recent
        assert cache.request((3,)).result(5) == 30        # evicts 2
        assert cache.cached((1,)) and cache.cached((3,)) and not cache.cached((2,))
        failed = cache.request((99,))
        with pytest.raises(ValueError):
            failed.result(5)
        assert not cache.cached((99,))
        retried = cache.request((99,))                    # a failure is not cached: retried
        assert retried is not failed
        with pytest.raises(ValueError):
            retried.result(5)
        assert all(name.startswith("viewer-frames") for _, name in calls)
        assert [frame for frame, _ in calls].count(1) == 1
        assert [frame for frame, _ in calls].count(99) == 2
    finally:
        cache.close()
    with pytest.raises(RuntimeError):
        cache.request((4,))


def test_frame_cache_close_cancels_queued_frames():
    started, release = threading.Event(), threading.Event()

    def prepare(frame: int) -> int:
        started.set()
        release.wait(5)
        return frame

    cache = FrameCache(prepare, capacity=8)
    running = cache.request((1,))
    queued = cache.request((2,))
    assert started.wait(5)          # frame 1 is being prepared, frame 2 waits in the queue
    closer = threading.Thread(target=cache.close)
    closer.start()
    release.set()
    closer.join(5)
    assert not closer.is_alive()
    assert running.result(1) == 1
    with pytest.raises(CancelledError):
        queued.result(1)


def test_simulation_source_is_the_renderers_frame(block_sim: Path):
    source = SimulationSource(block_sim, CPU)
    assert source.frames == [0, 1] and source.object_names == ["block"]
    sim = Simulation.open(block_sim)
    frame = sim.load_frame(1)
    expected = SceneGaussians.from_simulation(sim, CPU).frame(frame, fpgo=True)
    prepared = source.prepare(1, True)
    assert prepared.gaussians == len(expected) and prepared.fpgo_gaussians > 0
    assert prepared.fractured_particles == int(frame.fractured.sum())
    splats = prepared.objects[0]
    np.testing.assert_allclose(splats.centers / source.unit_scale, expected.means.numpy(),
                               atol=1e-6)
    np.testing.assert_allclose(splats.covariances / source.unit_scale ** 2,   # float16
                               expected.covariances.numpy(), rtol=1e-3,
                               atol=1e-3 * float(expected.covariances.abs().max()))
    without = source.prepare(1, False)
    assert without.fpgo_gaussians == 0 and without.gaussians < prepared.gaussians
    assert source.diagnostics(1) == {}     # this folder has no diagnostics.csv


def test_a_broken_frame_is_reported_in_the_gui_and_the_viewer_keeps_serving(block_sim: Path,
                                                                           tmp_path: Path):
    sim = tmp_path / "sim"
    shutil.copytree(block_sim, sim)
    source = SimulationSource(sim, CPU)
    (sim / "frames" / "frame_00001.npz").write_bytes(b"not an npz")
    viewer = Viewer(source, ViewerOptions(port=0))
    viewer.start()
    try:
        assert viewer.wait_until_shown(0, timeout=30)
        viewer.gui["frame"].value = 1
        assert viewer.wait_until_shown(1, timeout=30)
        status = viewer.gui["status"].value
        assert "frame_00001.npz" in status and "not a readable .npz" in status
        viewer.gui["frame"].value = 0
        assert viewer.wait_until_shown(0, timeout=30)
        assert viewer.gui["status"].value == "frame 0 shown"
    finally:
        viewer.stop()


def test_frame_diagnostics_reach_the_gui(block_sim: Path, tmp_path: Path):
    sim = tmp_path / "sim"
    shutil.copytree(block_sim, sim)
    (sim / "diagnostics.csv").write_text(
        "frame,time,steps,dt_min,px,py,pz,kinetic,elastic,gravitational,total_energy,fractured\n"
        "0,0.0,0,0.001,0.0,0.0,0.0,0.0,0.0,0.5,0.5,0\n"
        "1,0.01,4,0.001,3.0,0.0,-4.0,0.25,0.125,0.0625,0.4375,12\n")
    source = SimulationSource(sim, CPU)
    assert source.diagnostics(1)["momentum"] == pytest.approx(5.0)
    viewer = Viewer(source, ViewerOptions(port=0, start_frame=1))
    viewer.start()
    try:
        assert viewer.wait_until_shown(1, timeout=30)
        shown = {name: handle.value for name, handle in viewer.gui["diagnostics"].items()}
        assert shown == pytest.approx({"time": 0.01, "momentum": 5.0, "px": 3.0, "py": 0.0,
                                       "pz": -4.0, "kinetic": 0.25, "elastic": 0.125,
                                       "gravitational": 0.0625, "total_energy": 0.4375})
        node = viewer._nodes[0]
        prepared = viewer.cache.request((1, True)).result(30)
        np.testing.assert_array_equal(np.asarray(node.buffer), prepared.objects[0].buffer)
        viewer.gui["highlight"].value = True          # fractured Gaussians re-sent in magenta
        assert wait_for(lambda: viewer.shown == (1, True, True, False, False), 30)
        np.testing.assert_array_equal(np.asarray(node.buffer), prepared.objects[0].packed(True))
        assert prepared.objects[0].fractured.any() and not prepared.objects[0].fractured.all()
        viewer.gui["objects"][0].value = False        # per-object visibility
        assert not node.visible
        viewer.gui["objects"][0].value = True
        assert node.visible
    finally:
        viewer.stop()


def test_model_source_shows_the_trained_gaussians(tmp_path: Path):
    points, surface = lattice_block((0.05, 0.05, 0.05))
    model = write_model(tmp_path / "model", points, surface)
    source = ModelSource(tmp_path / "model", CPU)
    prepared = source.prepare(0, True)
    assert source.frames == [0] and not source.has_fracture
    assert prepared.gaussians == model.num_gaussians
    np.testing.assert_allclose(prepared.objects[0].centers / source.unit_scale,
                               model.means.detach().numpy(), atol=1e-6)
    viewer = Viewer(source, ViewerOptions(port=0))
    viewer.start()
    try:
        assert viewer.wait_until_shown(0, timeout=30)
        assert not viewer.gui["fpgo"].visible and not viewer.gui["highlight"].visible
        assert not viewer.gui["pieces"].visible
        assert viewer.gui["diagnostics"] == {} and viewer.gui["frame"].disabled
        assert viewer.gui["numbers"]["gaussians"].value == model.num_gaussians
    finally:
        viewer.stop()


def _error_line(main, argv: list[str], capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and "Traceback" not in err
    return err


def test_bad_folders_give_the_same_error_as_render(block_sim: Path, tmp_path: Path, capsys):
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "scene.yaml").write_text((block_sim / "scene.yaml").read_text())
    for folder in (tmp_path / "missing", tmp_path, broken):
        view_error = _error_line(view_cli.main, [str(folder), "--port", "0"], capsys)
        render_error = _error_line(render_cli.main, ["--sim", str(folder)], capsys)
        assert view_error == render_error
    model_error = _error_line(view_cli.main, ["-m", str(tmp_path / "nomodel"), "--port", "0"],
                              capsys)
    assert "nomodel" in model_error
    assert "exactly one" in _error_line(view_cli.main, [], capsys)
    assert "--frame 7" in _error_line(view_cli.main, [str(block_sim), "--frame", "7",
                                                      "--port", "0"], capsys)


def test_a_taken_port_is_one_clear_line(block_sim: Path, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        with pytest.raises(PortInUseError):
            check_port_free("127.0.0.1", port)
        error = _error_line(view_cli.main, [str(block_sim), "--port", str(port)], capsys)
    assert f"--port {port}" in error and "already in use" in error


def _visit(port: int, seconds: float) -> None:
    """Be a viser client for ``seconds``, then leave."""
    probe = WebsocketProbe(port)
    time.sleep(seconds)
    assert probe.arrivals, "the server sent nothing to the client"
    probe.close()


def _live_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


def test_viewer_ends_after_the_last_client_left_and_leaves_no_thread(block_sim: Path):
    before = _live_threads()
    viewer = Viewer(SimulationSource(block_sim, CPU),
                    ViewerOptions(port=0, grace_seconds=0.5, play_fps=30))
    viewer.start()
    try:
        port = int(viewer.url.rsplit(":", 1)[1])
        assert viewer.wait_until_shown(0, timeout=30)
        viewer.set_playing(True)                      # the loop advances frames by itself
        assert viewer.wait_until_shown(1, timeout=30)
        viewer.set_playing(False)
        assert not viewer.stop_requested.is_set()     # no browser yet: waits indefinitely
        _visit(port, 0.5)
        assert viewer.stop_requested.wait(10), "the viewer kept running without a client"
        assert viewer.client_count == 0
    finally:
        viewer.stop()
    deadline = time.monotonic() + 5
    while _live_threads() - before and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _live_threads() - before == set()


def test_keep_alive_ignores_the_browser_leaving(block_sim: Path):
    viewer = Viewer(SimulationSource(block_sim, CPU),
                    ViewerOptions(port=0, grace_seconds=0.2, keep_alive=True))
    viewer.start()
    try:
        _visit(int(viewer.url.rsplit(":", 1)[1]), 0.3)
        assert not viewer.stop_requested.wait(1.0)
    finally:
        viewer.stop()


def test_ctrl_c_stops_the_viewer_process(block_sim: Path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.Popen([sys.executable, str(REPO / "view.py"), str(block_sim), "--port",
                                "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=env, cwd=REPO)
    try:
        for line in process.stdout:
            if line.startswith("viewer: http://"):
                break
        else:
            pytest.fail(f"the viewer did not start: {process.stderr.read()}")
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err
    assert "viewer stopped (interrupted)" in out
    assert "Traceback" not in err
