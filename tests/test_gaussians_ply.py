"""GaussianModel activations and the 3DGS PLY layout (incl. channel-major f_rest)."""
from __future__ import annotations

import math
import os

import numpy as np
import plyfile
import pytest
import torch

from fracture_gs.gaussians import (GaussianModel, PlyFormatError, SH_C0, ply_property_names,
                                   read_ply, rgb_to_sh_dc, write_ply)


def random_model(count: int, sh_degree: int, isotropic: bool, seed: int = 0) -> GaussianModel:
    generator = torch.Generator().manual_seed(seed)
    rest = (sh_degree + 1) ** 2 - 1
    return GaussianModel(torch.randn(count, 3, generator=generator),
                         torch.randn(count, 1, 3, generator=generator),
                         torch.randn(count, rest, 3, generator=generator),
                         torch.randn(count, 1, generator=generator),
                         torch.randn(count, 1 if isotropic else 3, generator=generator),
                         torch.randn(count, 4, generator=generator))


def original_3dgs_vertices(count: int = 4, sh_degree: int = 3) -> tuple[np.ndarray, dict]:
    """A vertex array laid out as the original 3DGS ``save_ply`` does, written by hand:
    f_rest_{c*(K-1)+k} holds channel c of coefficient k+1. Every value encodes its slot."""
    rest = (sh_degree + 1) ** 2 - 1
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
             + [f"f_rest_{i}" for i in range(3 * rest)]
             + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    vertices = np.zeros(count, dtype=[(name, "f4") for name in names])
    truth = {"rest": np.zeros((count, rest, 3), np.float32)}
    for gaussian in range(count):
        for coefficient in range(rest):
            for channel in range(3):
                value = 1000 * gaussian + 10 * coefficient + channel
                vertices[f"f_rest_{channel * rest + coefficient}"][gaussian] = value
                truth["rest"][gaussian, coefficient, channel] = value
        for channel in range(3):
            vertices[f"f_dc_{channel}"][gaussian] = gaussian + 0.1 * channel
    vertices["x"], vertices["y"], vertices["z"] = np.arange(count), 2.0, -1.0
    opacities = np.linspace(0.1, 0.9, count)
    vertices["opacity"] = np.log(opacities / (1 - opacities))
    vertices["scale_0"], vertices["scale_1"], vertices["scale_2"] = np.log(1.0), np.log(2.0), np.log(3.0)
    # quaternion of a 90 degree turn about z, stored unnormalised (times 2)
    vertices["rot_0"], vertices["rot_3"] = 2 * math.cos(math.pi / 4), 2 * math.sin(math.pi / 4)
    truth["opacity"] = opacities
    return vertices, truth


def without_field(vertices: np.ndarray, dropped: str) -> np.ndarray:
    names = [name for name in vertices.dtype.names if name != dropped]
    result = np.zeros(len(vertices), dtype=[(name, "f4") for name in names])
    for name in names:
        result[name] = vertices[name]
    return result


def write_vertices(path, vertices):
    plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")]).write(str(path))


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
@pytest.mark.parametrize("isotropic", [False, True])
def test_round_trip_is_bit_exact(tmp_path, sh_degree, isotropic):
    model = random_model(37, sh_degree, isotropic, seed=sh_degree)
    path = tmp_path / "out" / "point_cloud.ply"
    write_ply(str(path), model)
    loaded = read_ply(str(path), isotropic=isotropic)
    assert loaded.sh_degree == sh_degree and loaded.isotropic == isotropic
    for name, tensor in model.raw_tensors().items():
        assert torch.equal(loaded.raw_tensors()[name], tensor), name
    ply = plyfile.PlyData.read(str(path))
    assert ply.byte_order == "<" and not ply.text
    assert [p.name for p in ply["vertex"].properties] == ply_property_names(sh_degree)
    assert all(p.val_dtype in ("f4", "float32") for p in ply["vertex"].properties)
    if isotropic:
        assert np.array_equal(ply["vertex"]["scale_0"], ply["vertex"]["scale_2"])
    assert [n for n in os.listdir(tmp_path / "out")] == ["point_cloud.ply"]


def test_original_3dgs_file_loads_with_right_layout_and_activations(tmp_path):
    vertices, truth = original_3dgs_vertices()
    path = tmp_path / "point_cloud.ply"
    write_vertices(path, vertices)
    model = read_ply(str(path))
    assert model.sh_degree == 3 and model.sh.shape == (4, 16, 3)
    assert np.array_equal(model.sh_rest.detach().numpy(), truth["rest"])
    # coefficient 5 (sh index 6), green channel, of Gaussian 2 sits in f_rest_{1*15+5}
    assert model.sh[2, 6, 1].item() == vertices["f_rest_20"][2] == 2051
    torch.testing.assert_close(model.sh[:, 0, :], torch.tensor(
        [[g + 0.1 * c for c in range(3)] for g in range(4)], dtype=torch.float32))
    torch.testing.assert_close(model.opacities, torch.tensor(truth["opacity"], dtype=torch.float32))
    torch.testing.assert_close(model.scales, torch.tensor([[1.0, 2.0, 3.0]]).expand(4, 3))
    torch.testing.assert_close(model.rotations[0], torch.tensor([math.sqrt(0.5), 0, 0, math.sqrt(0.5)]))
    # R_z(90) diag(1,4,9) R_z(90)^T = diag(4,1,9)
    torch.testing.assert_close(model.covariances(), torch.diag(torch.tensor([4.0, 1.0, 9.0]))
                               .expand(4, 3, 3), atol=1e-5, rtol=0)
    assert model.means[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]


def test_our_file_matches_the_original_writer_byte_for_byte(tmp_path):
    vertices, _ = original_3dgs_vertices()
    reference = tmp_path / "reference.ply"
    write_vertices(reference, vertices)
    ours = tmp_path / "ours.ply"
    write_ply(str(ours), read_ply(str(reference)))
    assert ours.read_bytes() == reference.read_bytes()


def test_covariance_matches_explicit_product():
    model = random_model(20, 1, False, seed=3)
    quats = model.rotations.detach()
    for index in (0, 7, 19):
        w, x, y, z = quats[index].tolist()
        rotation = torch.tensor([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        scale = torch.diag(torch.exp(model.log_scales[index].detach()))
        torch.testing.assert_close(model.covariances()[index].detach(),
                                   rotation @ scale @ scale @ rotation.T, atol=1e-5, rtol=1e-5)
        assert torch.linalg.det(rotation).item() == pytest.approx(1.0, abs=1e-5)


def test_from_points_initialisation_and_helpers():
    grid = torch.stack(torch.meshgrid(*[torch.arange(4.0) * 0.5] * 3, indexing="ij"), -1).reshape(-1, 3)
    colors = torch.rand(64, 3, generator=torch.Generator().manual_seed(1))
    model = GaussianModel.from_points(grid, colors, sh_degree=2, isotropic=True)
    assert model.isotropic and model.sh_degree == 2 and model.log_scales.shape == (64, 1)
    # every grid point has at least three neighbours at distance 0.5
    torch.testing.assert_close(model.scales, torch.full((64, 3), 0.5))
    torch.testing.assert_close(model.sh_dc[:, 0] * SH_C0 + 0.5, colors)
    torch.testing.assert_close(model.opacities, torch.full((64,), 0.1))
    assert torch.equal(model.sh_dc[:, 0], rgb_to_sh_dc(colors))
    groups = model.param_groups(spatial_lr_scale=2.0)
    assert sum(len(g["params"]) for g in groups) == len(list(model.parameters())) == 6
    assert groups[0]["lr"] == pytest.approx(3.2e-4)
    torch.optim.Adam(groups)  # accepted by an optimiser
    part = model.select(torch.arange(64) % 2 == 0)
    both = GaussianModel.concatenate([part, model.select(torch.tensor([1, 3]))])
    assert len(part) == 32 and len(both) == 34
    assert torch.equal(both.means[33], model.means[3])
    with pytest.raises(ValueError, match="log_scales"):
        GaussianModel(grid, model.sh_dc, model.sh_rest, model.opacity_logit,
                      torch.zeros(64, 2), model.quats)


def test_missing_property_is_named(tmp_path):
    vertices, _ = original_3dgs_vertices(sh_degree=1)
    path = tmp_path / "no_rot.ply"
    write_vertices(path, without_field(vertices, "rot_2"))
    with pytest.raises(PlyFormatError, match=r"no_rot\.ply: missing property 'rot_2'"):
        read_ply(str(path))


def test_bad_f_rest_count_is_refused(tmp_path):
    vertices, _ = original_3dgs_vertices(sh_degree=1)  # 9 f_rest
    extra = [f"f_rest_{i}" for i in range(9, 12)]
    dtype = vertices.dtype.descr + [(name, "f4") for name in extra]
    widened = np.zeros(len(vertices), dtype=dtype)
    for name in vertices.dtype.names:
        widened[name] = vertices[name]
    path = tmp_path / "twelve.ply"
    write_vertices(path, widened)
    with pytest.raises(PlyFormatError, match=r"twelve\.ply: 12 f_rest_\* properties"):
        read_ply(str(path))
    path = tmp_path / "gap.ply"
    write_vertices(path, without_field(vertices, "f_rest_4"))
    with pytest.raises(PlyFormatError, match=r"gap\.ply: f_rest_\* properties are not numbered"):
        read_ply(str(path))


def test_other_malformed_files(tmp_path):
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"not a ply at all")
    with pytest.raises(PlyFormatError, match=r"garbage\.ply: not a readable PLY"):
        read_ply(str(garbage))
    with pytest.raises(PlyFormatError, match=r"absent\.ply: file not found"):
        read_ply(str(tmp_path / "absent.ply"))
    vertices, _ = original_3dgs_vertices(sh_degree=0)
    vertices["opacity"][1] = np.nan
    path = tmp_path / "nan.ply"
    write_vertices(path, vertices)
    with pytest.raises(PlyFormatError, match=r"nan\.ply: property opacity contains NaN"):
        read_ply(str(path))
    vertices["opacity"][1] = 0.0
    write_vertices(path, vertices)
    with pytest.raises(PlyFormatError, match="not isotropic"):
        read_ply(str(path), isotropic=True)
    faces = tmp_path / "faces.ply"
    face = np.zeros(1, dtype=[("vertex_indices", "i4", (3,))])
    plyfile.PlyData([plyfile.PlyElement.describe(face, "face")]).write(str(faces))
    with pytest.raises(PlyFormatError, match=r"faces\.ply: no 'vertex' element"):
        read_ply(str(faces))


def test_writing_nan_fails_and_leaves_nothing(tmp_path):
    model = random_model(5, 0, False)
    with torch.no_grad():
        model.means[2, 1] = float("nan")
    with pytest.raises(ValueError, match="means"):
        write_ply(str(tmp_path / "bad.ply"), model)
    assert os.listdir(tmp_path) == []
