"""Animations from RGB frames: H.264 MP4 through imageio-ffmpeg, or an animated GIF where no encoder is available.

`encode_animation` returns the file's bytes and its suffix, so that the caller writes them through its own atomic
writer (a stage: pipeline.core.h5.atomic_write) under the right name, and an HTML page can embed them as
they are. The MP4 is what browsers and players expect: H.264, yuv420p (which needs even sizes: an odd frame is
padded by repeating its last row or column), `+faststart` (the index first, so playback starts before the whole
file arrives). imageio-ffmpeg ships its own ffmpeg binary, so the fallback matters only on a platform it has no
binary for and no system ffmpeg. Frames are streamed to the encoder one at a time: a long animation needs no
memory for all of its frames.
"""
from __future__ import annotations

import dataclasses
import io
import itertools
import math
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
from PIL import Image

MP4_QUALITY = 7            # imageio-ffmpeg's 0-10 scale: H.264 CRF 15, crisp lines on flat colour
GIF_MIN_DELAY_S = 0.02     # browsers show a GIF frame of < 20 ms for 100 ms: faster GIFs drop frames instead


@dataclasses.dataclass(frozen=True)
class EncodedAnimation:
    """An animation file's contents: write `data` to a path ending in `suffix`."""

    data: bytes
    suffix: str          # ".mp4" or ".gif"
    mime_type: str       # "video/mp4" or "image/gif"


def ffmpeg_executable() -> str | None:
    """The ffmpeg that imageio-ffmpeg would run (its bundled binary, else one on PATH), or None."""
    try:
        import imageio_ffmpeg          # imported here: without the package, animations fall back to GIF
        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return None


def encode_animation(frames: Iterable[np.ndarray], fps: float, allow_mp4: bool = True) -> EncodedAnimation:
    """MP4 of `frames` (RGB uint8 (H, W, 3), all one size) at `fps` frames per second if an encoder is available
    (and `allow_mp4`), else an animated GIF."""
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if allow_mp4 and ffmpeg_executable() is not None:
        return EncodedAnimation(encode_mp4(frames, fps), ".mp4", "video/mp4")
    return EncodedAnimation(encode_gif(frames, fps), ".gif", "image/gif")


def encode_mp4(frames: Iterable[np.ndarray], fps: float) -> bytes:
    """H.264 yuv420p MP4 bytes of the frames (odd sizes padded to even)."""
    import imageio_ffmpeg

    checked = _checked(frames)
    first = next(checked)
    height, width = first.shape[0] + first.shape[0] % 2, first.shape[1] + first.shape[1] % 2
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "animation.mp4"
        writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=fps, codec="libx264",
                                             pix_fmt_out="yuv420p", quality=MP4_QUALITY, macro_block_size=2,
                                             output_params=["-movflags", "+faststart"])
        writer.send(None)                                    # starts ffmpeg
        try:
            for frame in itertools.chain([first], checked):
                writer.send(np.ascontiguousarray(_pad_to(frame, height, width)))
        finally:
            writer.close()
        return path.read_bytes()


def encode_gif(frames: Iterable[np.ndarray], fps: float) -> bytes:
    """Looping animated GIF bytes of the frames (adaptive 256-colour palette per frame). Above 50 frames per
    second only every k-th frame is kept, so that the frame delay browsers honour keeps the real speed."""
    step = math.ceil(fps * GIF_MIN_DELAY_S - 1e-9)
    images = [Image.fromarray(frame).quantize(colors=256, method=Image.Quantize.MEDIANCUT)
              for i, frame in enumerate(_checked(frames)) if i % step == 0]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], loop=0,
                   duration=round(1000 * step / fps), disposal=1)
    return buffer.getvalue()


def _checked(frames: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """The frames, each verified to be RGB uint8 of the first one's size; ValueError for none or a bad one."""
    shape = None
    for i, frame in enumerate(frames):
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3 or min(frame.shape[:2]) < 1:
            raise ValueError(f"frame {i}: expected an RGB uint8 array (H, W, 3), got {frame.dtype} {frame.shape}")
        if shape is not None and frame.shape != shape:
            raise ValueError(f"frame {i}: size {frame.shape[:2]} differs from the first frame's {shape[:2]}")
        shape = frame.shape
        yield frame
    if shape is None:
        raise ValueError("an animation needs at least one frame")


def _pad_to(frame: np.ndarray, height: int, width: int) -> np.ndarray:
    """The frame grown to (height, width) by repeating its last row and column."""
    return np.pad(frame, ((0, height - frame.shape[0]), (0, width - frame.shape[1]), (0, 0)), mode="edge")
