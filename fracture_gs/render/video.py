"""Writing rendered frames: H.264 MP4 (browser-playable), GIF previews and PNG images.

Every file appears only when complete (written to a temporary name in the same folder, then
renamed), so an interrupted render never leaves a truncated video behind.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from fracture_gs.io.atomic import atomic_path, commit, discard, temporary_beside, write_bytes_atomic


def to_uint8(rgb: torch.Tensor) -> np.ndarray:
    """(H,W,3) float image in [0,1] → uint8 (rounded), on the CPU."""
    return (rgb.detach().clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an RGB uint8 image as PNG (atomic)."""
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    write_bytes_atomic(path, encoded.tobytes())


class Mp4Writer:
    """H.264 (yuv420p, +faststart) MP4 through the ffmpeg binary of ``imageio-ffmpeg``.

    Odd image sizes are padded by one row / column with the last one (yuv420p needs even
    sizes); the file is renamed into place by :meth:`close`.
    """

    def __init__(self, path: Path, width: int, height: int, fps: float) -> None:
        import imageio_ffmpeg

        self.path = path
        self.width, self.height = width, height
        self.frames = 0
        self._temporary = temporary_beside(path)
        self._size = (width + width % 2, height + height % 2)
        try:
            self._writer = imageio_ffmpeg.write_frames(
                str(self._temporary), self._size, fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                quality=8, macro_block_size=2, output_params=["-movflags", "+faststart"],
                ffmpeg_log_level="error")
            self._writer.send(None)
        except BaseException:
            discard(self._temporary)
            raise

    def write(self, image: np.ndarray) -> None:
        """Append an RGB uint8 (H, W, 3) frame."""
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"{self.path}: frame of {image.shape[1]}x{image.shape[0]}, the video "
                             f"is {self.width}x{self.height}")
        pad = ((0, self._size[1] - self.height), (0, self._size[0] - self.width), (0, 0))
        try:
            self._writer.send(np.ascontiguousarray(np.pad(image, pad, mode="edge")))
        except OSError as exc:  # ffmpeg stopped (a full disk): its message runs over many lines
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise OSError(exc.errno, f"the video encoder ffmpeg stopped ({reason})",
                          str(self.path)) from exc
        self.frames += 1

    def close(self) -> None:
        """Finish the file and move it into place."""
        self._writer.close()
        commit(self._temporary, self.path)

    def abort(self) -> None:
        """Stop without keeping a file (an encoder that fails to stop changes nothing: its
        output is discarded either way)."""
        try:
            self._writer.close()
        except (OSError, RuntimeError, ValueError):
            pass
        finally:
            discard(self._temporary)


def write_gif(path: Path, images: list[np.ndarray], fps: float, max_size: int = 320) -> None:
    """An animated GIF (looping) of RGB uint8 frames, shrunk to at most ``max_size`` pixels."""
    from PIL import Image

    if not images:
        raise ValueError(f"{path}: no frames for the GIF")
    height, width = images[0].shape[:2]
    factor = min(1.0, max_size / max(width, height))
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    frames = [Image.fromarray(image).resize(size, Image.LANCZOS) for image in images]
    with atomic_path(path) as temporary:
        frames[0].save(temporary, format="GIF", save_all=True, append_images=frames[1:],
                       duration=max(20, round(1000.0 / fps)), loop=0, optimize=True)
