"""One self-contained HTML page from typed pieces: it opens offline, with nothing beside it but linked files.

Pictures are embedded as data: URIs; videos too (an MP4 as a looping, muted, autoplaying <video>; a GIF, the
encoder's fallback, as an <img>). Links to exported files stay relative to the page, so the page and its folder
move together. Every string is HTML-escaped (titles, captions and table cells may come from config values);
`Paragraphs` understand a little markdown, applied to the escaped text: blank lines between paragraphs, lines
starting "- " as a list, `code` and **bold**; a table cell is bold as a `Strong`. `report_html` returns the page
as text for the caller's atomic writer (a stage: pipeline.core.h5.atomic_write(path).write(page.encode()));
viz/markdown_report.py writes the same pieces as markdown.
"""
from __future__ import annotations

import base64
import dataclasses
import html
import re
import urllib.parse
from pathlib import Path
from typing import Sequence

MIME_TYPES = {".png": "image/png", ".svg": "image/svg+xml", ".gif": "image/gif", ".jpg": "image/jpeg",
              ".jpeg": "image/jpeg", ".mp4": "video/mp4"}
STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1800px; padding: 0 1em; color: #222; }
h1 { font-size: 1.6em; }
h2 { font-size: 1.3em; border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .8em 0; } caption { text-align: left; color: #555; padding: .3em 0; }
th, td { border: 1px solid #ccc; padding: .3em .7em; text-align: right; } th { background: #f3f3f3; }
td:first-child, th:first-child { text-align: left; }
figure { margin: 1em 0; } figure img, figure video { max-width: 100%; height: auto; display: block; }
figcaption { color: #555; margin-top: .3em; } code { background: #f3f3f3; padding: 0 .2em; }
"""


@dataclasses.dataclass(frozen=True)
class Paragraphs:
    """Markdown-like text: paragraphs, "- " lists, `code`, **bold**."""

    text: str


@dataclasses.dataclass(frozen=True)
class Strong:
    """A table cell shown in bold (the lowest of a row, say): <strong> in HTML, **text** in markdown."""

    text: str


@dataclasses.dataclass(frozen=True)
class Table:
    header: Sequence[str]
    rows: Sequence[Sequence[str | int | float | Strong]]     # floats are shown with 4 significant digits
    caption: str = ""

    def __post_init__(self):
        for i, row in enumerate(self.rows):
            if len(row) != len(self.header):
                raise ValueError(f"table row {i} has {len(row)} cells, the header {len(self.header)}")


@dataclasses.dataclass(frozen=True)
class Picture:
    """An image file (PNG, SVG, GIF, JPEG), embedded."""

    path: Path
    caption: str = ""


@dataclasses.dataclass(frozen=True)
class Video:
    """An MP4 (or the GIF that stands in for one), embedded."""

    path: Path
    caption: str = ""


@dataclasses.dataclass(frozen=True)
class Links:
    """(label, path relative to the page) pairs, as a list of links."""

    links: Sequence[tuple[str, str]]

    def __post_init__(self):
        """Only relative paths: a URL with a scheme (such as javascript:) or an absolute path would not move
        with the page."""
        for _, href in self.links:
            parsed = urllib.parse.urlsplit(href)
            if parsed.scheme or parsed.netloc or href.startswith(("/", "\\")):
                raise ValueError(f"link {href!r}: expected a path relative to the report")


Piece = Paragraphs | Table | Picture | Video | Links


@dataclasses.dataclass(frozen=True)
class Section:
    heading: str
    pieces: Sequence[Piece]


def report_html(title: str, sections: Sequence[Section]) -> str:
    """The whole page."""
    body = "\n".join(f"<section>\n<h2>{_text(s.heading)}</h2>\n" + "\n".join(_piece(p) for p in s.pieces)
                     + "\n</section>" for s in sections)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{_text(title)}</title>\n'
            f"<style>{STYLE}</style>\n</head>\n<body>\n<h1>{_text(title)}</h1>\n{body}\n</body>\n</html>\n")


def _text(value: object) -> str:
    return html.escape(str(value), quote=True)


def _piece(piece: Piece) -> str:
    if isinstance(piece, Paragraphs):
        return _paragraphs(piece.text)
    if isinstance(piece, Table):
        return _table(piece)
    if isinstance(piece, Picture):
        return _figure(f'<img src="{_data_uri(piece.path)}" alt="{_text(piece.caption or piece.path.name)}">',
                       piece.caption)
    if isinstance(piece, Video):
        uri = _data_uri(piece.path)
        if uri.startswith("data:image/"):
            media = f'<img src="{uri}" alt="{_text(piece.caption or piece.path.name)}">'
        else:
            media = f'<video src="{uri}" autoplay loop muted playsinline controls></video>'
        return _figure(media, piece.caption)
    if isinstance(piece, Links):
        items = "".join(f'<li><a href="{_text(urllib.parse.quote(href))}">{_text(label)}</a></li>' for label, href in piece.links)
        return f"<ul>{items}</ul>"
    raise TypeError(f"not a report piece: {type(piece).__name__}")


def _figure(media: str, caption: str) -> str:
    return f"<figure>{media}" + (f"<figcaption>{_text(caption)}</figcaption>" if caption else "") + "</figure>"


def _inline(escaped: str) -> str:
    """`code` and **bold** in already escaped text (neither ` nor * is touched by escaping)."""
    escaped = re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)
    return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", escaped)


def _paragraphs(text: str) -> str:
    blocks = [b.strip() for b in re.split(r"\n\s*\n", text) if b.strip()]
    out = []
    for block in blocks:
        lines = block.splitlines()
        if all(line.lstrip().startswith("- ") for line in lines):
            out.append("<ul>" + "".join(f"<li>{_inline(_text(line.lstrip()[2:]))}</li>" for line in lines) + "</ul>")
        else:
            out.append(f"<p>{_inline(_text(' '.join(line.strip() for line in lines)))}</p>")
    return "\n".join(out)


def cell_text(value: str | int | float | Strong) -> str:
    """A table cell's text, unescaped (viz.markdown_report shows cells alike; it marks a Strong cell itself)."""
    if isinstance(value, Strong):
        return value.text
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _cell(value: str | int | float | Strong) -> str:
    text = _text(cell_text(value))
    return f"<td><strong>{text}</strong></td>" if isinstance(value, Strong) else f"<td>{text}</td>"


def _table(table: Table) -> str:
    caption = f"<caption>{_text(table.caption)}</caption>" if table.caption else ""
    head = "".join(f"<th>{_text(h)}</th>" for h in table.header)
    rows = "".join("<tr>" + "".join(_cell(c) for c in row) + "</tr>" for row in table.rows)
    return f"<table>{caption}<thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def _data_uri(path: Path) -> str:
    mime = MIME_TYPES.get(Path(path).suffix.lower())
    if mime is None:
        raise ValueError(f"{path}: cannot embed a '{Path(path).suffix}' file (known: {', '.join(MIME_TYPES)})")
    return f"data:{mime};base64,{base64.b64encode(Path(path).read_bytes()).decode('ascii')}"
