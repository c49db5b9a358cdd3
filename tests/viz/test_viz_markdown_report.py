"""report.md from the same pieces as report.html: tables, pictures and links that a markdown reader parses as such."""
from __future__ import annotations

from pathlib import Path

import pytest

from viz.html_report import Links, Paragraphs, Picture, Section, Table, Video
from viz.markdown_report import report_markdown


def test_pieces_become_markdown_with_links_where_the_files_will_be():
    staged = Path("/tmp/.renders.x1")
    page = report_markdown("Evaluation", [
        Section("Errors", [Table(["", "L1", "a | b"], [["network", 0.123456, 3]], "x 1e-3"),
                           Paragraphs("Some **bold**.\n\n- one\n- two")]),
        Section("Pictures", [Picture(staged / "frame_0001.png", "frame 1"), Video(staged / "walk.mp4")]),
        Section("Files", [Links([("OBJ (all frames)", "export/predicted obj")])]),
    ], href=lambda path: f"renders/{path.name}")
    assert page.startswith("# Evaluation\n\n## Errors\n\nx 1e-3\n\n")
    # The cell's pipe is escaped (it would split the column); floats to 4 significant digits, as on the page.
    assert "|  | L1 | a \\| b |\n| --- | --- | --- |\n| network | 0.1235 | 3 |" in page
    assert "Some **bold**.\n\n- one\n- two" in page
    assert "![frame 1](renders/frame_0001.png)" in page and "[walk.mp4](renders/walk.mp4)" in page
    assert "- [OBJ (all frames)](export/predicted%20obj)" in page       # a space would end the link
    assert page.index("## Pictures") < page.index("## Files")


def test_bad_pieces_are_refused():
    with pytest.raises(ValueError):
        Table(["a", "b"], [["only one"]])
    with pytest.raises(ValueError):
        Links([("x", "https://example.com/x")])
    with pytest.raises(TypeError):
        report_markdown("t", [Section("s", ["not a piece"])], href=str)
