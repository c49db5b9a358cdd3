"""The HTML report: every piece on the page, every string escaped, every file embedded byte for byte."""
from __future__ import annotations

import base64
import html.parser
import re

import numpy as np
import pytest

from viz.animation import encode_animation
from viz.html_report import Links, Paragraphs, Picture, Section, Table, Video, report_html
from viz.render import png_bytes

HOSTILE = '<script>alert("x")</script> & \'quoted\''


class Page(html.parser.HTMLParser):
    """Tags with their attributes, and the text, of a page as a browser's parser reads it."""

    def __init__(self, text: str):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.text: list[str] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)

    def all(self, tag):
        return [attrs for name, attrs in self.tags if name == tag]


def example_page(tmp_path) -> tuple[str, dict]:
    image = np.zeros((6, 8, 3), np.uint8)
    image[:, :4] = (255, 0, 0)
    files = {"png": tmp_path / "r.png", "mp4": tmp_path / "v.mp4", "gif": tmp_path / "v.gif"}
    files["png"].write_bytes(png_bytes(image))
    files["mp4"].write_bytes(encode_animation([image, image[::-1]], fps=5).data)
    files["gif"].write_bytes(encode_animation([image, image[::-1]], fps=5, allow_mp4=False).data)
    page = report_html(f"Scene {HOSTILE}", [
        Section("Errors", [Paragraphs(f"First `code` and **bold**.\n\n- one {HOSTILE}\n- two"),
                           Table(["", "L1", HOSTILE], [["network", 0.123456, 3], [HOSTILE, 1.0, "x"]], HOSTILE)]),
        Section("Pictures", [Picture(files["png"], f"render {HOSTILE}"), Video(files["mp4"], "held-out walk"),
                             Video(files["gif"], "fallback")]),
        Section("Files", [Links([("OBJ sequence", "export/predicted obj/"), (HOSTILE, "eval.h5")])]),
    ])
    return page, files


def data_uri_bytes(uri: str, mime: str) -> bytes:
    prefix = f"data:{mime};base64,"
    assert uri.startswith(prefix)
    return base64.b64decode(uri[len(prefix):])


def test_every_piece_is_on_the_page_and_embedded(tmp_path):
    page, files = example_page(tmp_path)
    parsed = Page(page)
    assert [t for t in parsed.text if "Scene" in t] == [f"Scene {HOSTILE}"] * 2          # <title> and <h1>
    assert [a for a in parsed.tags if a[0] == "h2"] and "".join(parsed.text).count("Errors") == 1
    assert "<code>code</code>" in page and "<strong>bold</strong>" in page
    assert len(parsed.all("li")) == 4                                  # two list lines, two links
    assert len(parsed.all("tr")) == 3 and len(parsed.all("th")) == 3 and len(parsed.all("td")) == 6
    assert "0.1235" in parsed.text and "3" in parsed.text              # floats to 4 significant digits
    images, videos = parsed.all("img"), parsed.all("video")
    assert len(images) == 2 and len(videos) == 1
    assert data_uri_bytes(images[0]["src"], "image/png") == files["png"].read_bytes()
    assert data_uri_bytes(images[1]["src"], "image/gif") == files["gif"].read_bytes()
    assert data_uri_bytes(videos[0]["src"], "video/mp4") == files["mp4"].read_bytes()
    assert {"autoplay", "loop", "muted", "playsinline"} <= set(videos[0])
    assert [a["href"] for a in parsed.all("a")] == ["export/predicted%20obj/", "eval.h5"]
    assert "render " + HOSTILE in parsed.text and "held-out walk" in parsed.text


def test_strings_are_escaped(tmp_path):
    page, _ = example_page(tmp_path)
    assert "<script" not in page and "alert" in page                   # shown, never run
    # <title>, <h1>, list item, header, cell, caption, picture caption and its alt text, link label.
    assert len(re.findall(re.escape("&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; &#x27;quoted&#x27;"),
                          page)) == 9


@pytest.mark.parametrize("href", ["javascript:alert(1)", "/etc/passwd", "https://example.com/x", "//host/x"])
def test_links_must_be_relative(href):
    with pytest.raises(ValueError):
        report_html("t", [Section("s", [Links([("x", href)])])])


def test_bad_pieces_are_refused(tmp_path):
    with pytest.raises(ValueError):
        report_html("t", [Section("s", [Table(["a", "b"], [["only one"]])])])
    (tmp_path / "x.bmp").write_bytes(b"BM")
    with pytest.raises(ValueError):
        report_html("t", [Section("s", [Picture(tmp_path / "x.bmp")])])
