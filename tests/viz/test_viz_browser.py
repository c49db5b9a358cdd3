"""report.html as a person sees it: headless Chromium opens the page offline, shows its pictures and plays its
video. Skipped where Chromium is absent; on Debian/Ubuntu install it with `apt-get install -y chromium`."""
from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

from viz.animation import encode_animation
from viz.html_report import Paragraphs, Picture, Section, Table, Video, report_html
from viz.render import png_bytes

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None,
                                reason="chromium is not on PATH (Debian: apt-get install -y chromium)")
RED = (220, 20, 20)
# Appended to a copy of the page: after load, records on <body> every picture that did not decode and every video
# that cannot show its frames (readyState < HAVE_CURRENT_DATA, or a media error), for --dump-dom to print.
MEDIA_CHECK = """<script>
window.addEventListener("load", () => setTimeout(() => {
  const bad = [];
  document.querySelectorAll("img").forEach((m, i) => {
    if (!(m.complete && m.naturalWidth > 0)) bad.push("img " + i); });
  document.querySelectorAll("video").forEach((v, i) => {
    if (v.error || v.readyState < 2) bad.push("video " + i + ": " + (v.error ? v.error.message : v.readyState)); });
  document.body.setAttribute("data-media-check", bad.length ? bad.join("; ") : "ok");
}, 300));
</script>"""


def chromium(*args: str) -> str:
    # --no-sandbox: Chromium refuses to start as root otherwise (containers, CI); the page is our own.
    run = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                          "--virtual-time-budget=5000", *args], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def test_report_opens_offline_with_pictures_and_video(tmp_path):
    picture = np.full((120, 240, 3), 255, np.uint8)
    picture[:, :160] = RED
    frames = [np.roll(picture, 8 * i, axis=1) for i in range(6)]
    (tmp_path / "render.png").write_bytes(png_bytes(picture))
    animation = encode_animation(frames, fps=6)
    (tmp_path / f"walk{animation.suffix}").write_bytes(animation.data)
    page = report_html("Report", [Section("Results", [Paragraphs("Some **text**."), Table(["a", "b"], [[1, 2.5]]),
                                                      Picture(tmp_path / "render.png", "render"),
                                                      Video(tmp_path / f"walk{animation.suffix}", "walk")])])
    (tmp_path / "report.html").write_text(page)
    (tmp_path / "checked.html").write_text(page.replace("</body>", MEDIA_CHECK + "</body>"))

    dom = chromium("--dump-dom", (tmp_path / "checked.html").as_uri())
    assert 'data-media-check="ok"' in dom, dom[dom.find("<body"):][:300]

    chromium("--window-size=900,700", f"--screenshot={tmp_path / 'shot.png'}", (tmp_path / "report.html").as_uri())
    shot = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB")).astype(int)
    assert shot.shape[:2] == (700, 900)
    assert (shot.min(axis=2) < 200).mean() > 0.02                      # not blank: text, table, picture
    red = (np.abs(shot - RED).max(axis=2) < 30).sum()
    assert red >= 0.8 * 120 * 160                                      # the picture's red block, at full size
