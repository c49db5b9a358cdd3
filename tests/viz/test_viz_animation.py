"""Animations decoded back: frame count, size, colours and rate, for the MP4 and for the GIF fallback."""
from __future__ import annotations

import io

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image, ImageSequence

import viz.animation
from viz.animation import encode_animation

COLOURS = [(230, 30, 30), (30, 200, 40), (40, 60, 220), (250, 250, 250), (10, 10, 10)]


def frames(height=37, width=50):
    """One flat colour per frame, odd-sized (the MP4 must pad it), with a black square to the top left."""
    for colour in COLOURS:
        frame = np.empty((height, width, 3), dtype=np.uint8)
        frame[:] = colour
        frame[:8, :8] = 0
        yield frame


def test_mp4_round_trip(tmp_path):
    animation = encode_animation(frames(), fps=12)
    assert (animation.suffix, animation.mime_type) == (".mp4", "video/mp4")
    path = tmp_path / f"a{animation.suffix}"
    path.write_bytes(animation.data)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p") and meta["fps"] == 12
    assert meta["size"] == (50, 38)                                    # even: one row repeated
    decoded = [np.frombuffer(f, np.uint8).reshape(38, 50, 3) for f in reader]
    assert len(decoded) == len(COLOURS)
    for image, colour in zip(decoded, COLOURS):
        assert np.abs(image[20:, 20:].astype(int) - colour).max() <= 12   # lossy, but the colour is right
        assert image[:6, :6].max() <= 20
        np.testing.assert_allclose(image[-1, 20:], image[-2, 20:], atol=12)   # the padding repeats the last row


def gif_frames(data: bytes) -> tuple[list[np.ndarray], list[int]]:
    image = Image.open(io.BytesIO(data))
    assert image.format == "GIF" and image.info["loop"] == 0
    decoded, delays = [], []
    for frame in ImageSequence.Iterator(image):
        decoded.append(np.asarray(frame.convert("RGB")))
        delays.append(frame.info["duration"])
    return decoded, delays


def test_gif_fallback_when_no_encoder(monkeypatch):
    monkeypatch.setattr(viz.animation, "ffmpeg_executable", lambda: None)
    animation = encode_animation(frames(), fps=10)
    assert (animation.suffix, animation.mime_type) == (".gif", "image/gif")
    decoded, delays = gif_frames(animation.data)
    assert len(decoded) == len(COLOURS) and delays == [100] * len(COLOURS)
    for image, colour in zip(decoded, COLOURS):
        assert image.shape == (37, 50, 3)                              # a GIF keeps odd sizes
        assert np.abs(image[20:, 20:].astype(int) - colour).max() <= 4 and image[:8, :8].max() <= 4


def test_fast_gif_drops_frames_to_keep_real_speed():
    decoded, delays = gif_frames(encode_animation(frames(), fps=60, allow_mp4=False).data)
    # 60 fps is a 17 ms delay, which browsers would show as 100 ms: every other frame, 33 ms (GIF: 30 ms) each.
    assert len(decoded) == 3 and set(delays) == {30}
    assert np.abs(decoded[1][20, 20].astype(int) - COLOURS[2]).max() <= 4


@pytest.mark.parametrize("bad", [[np.zeros((4, 4, 3), np.float32)], [np.zeros((4, 4), np.uint8)],
                                 [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 6, 3), np.uint8)], []])
def test_bad_frames_are_refused(bad):
    for allow_mp4 in (True, False):
        with pytest.raises(ValueError):
            encode_animation(iter(bad), fps=10, allow_mp4=allow_mp4)
