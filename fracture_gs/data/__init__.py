"""Dataset loaders (docs/file_formats.md §1): Blender/NeRF-synthetic, COLMAP and DTU/IDR/NeuS scenes become a
:class:`Dataset` of OpenCV-convention :class:`~fracture_gs.render.camera.Camera` objects,
images, optional masks and (COLMAP) sparse points."""
from fracture_gs.data.blender import load_blender
from fracture_gs.data.colmap import load_colmap
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.dtu import load_dtu
from fracture_gs.data.loading import detect_format, load_dataset

__all__ = ["Dataset", "DatasetError", "detect_format", "load_blender", "load_colmap",
           "load_dataset", "load_dtu"]
