"""3D Gaussians: the raw-parameter model and its standard 3DGS PLY file format."""
from fracture_gs.gaussians.model import (SH_C0, GaussianModel, num_sh_coefficients,
                                         quaternion_to_rotation_matrix, rgb_to_sh_dc,
                                         sh_dc_to_rgb, sh_degree_of)
from fracture_gs.gaussians.ply import PlyFormatError, ply_property_names, read_ply, write_ply

__all__ = ["GaussianModel", "PlyFormatError", "SH_C0", "num_sh_coefficients",
           "ply_property_names", "quaternion_to_rotation_matrix", "read_ply", "rgb_to_sh_dc",
           "sh_dc_to_rgb", "sh_degree_of", "write_ply"]
