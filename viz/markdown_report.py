"""The pieces of viz/html_report.py as a markdown page, for terminals and repositories: paragraphs as written,
tables as pipe tables, pictures shown (`![caption](path)`), videos and other files linked.

A markdown page embeds nothing, so pictures and videos are linked by `href(path)`, a path relative to the page
(a stage that writes its files into a temporary folder first maps each one to where it will end up).
"""
from __future__ import annotations

import urllib.parse
from pathlib import Path
from typing import Callable, Sequence

from viz.html_report import Links, Paragraphs, Picture, Piece, Section, Strong, Table, Video, cell_text


def report_markdown(title: str, sections: Sequence[Section], href: Callable[[Path], str]) -> str:
    """The whole page."""
    parts = [f"# {title}"]
    for section in sections:
        parts.append(f"## {section.heading}")
        parts += [_piece(piece, href) for piece in section.pieces]
    return "\n\n".join(parts) + "\n"


def _piece(piece: Piece, href: Callable[[Path], str]) -> str:
    if isinstance(piece, Paragraphs):
        return piece.text.strip()
    if isinstance(piece, Table):
        rows = [piece.header, ["---"] * len(piece.header), *piece.rows]
        table = "\n".join("| " + " | ".join(_cell(c) for c in row) + " |" for row in rows)
        return f"{piece.caption}\n\n{table}" if piece.caption else table
    if isinstance(piece, Picture):
        return f"![{piece.caption or piece.path.name}]({_target(href(piece.path))})"
    if isinstance(piece, Video):
        return f"Video: [{piece.caption or piece.path.name}]({_target(href(piece.path))})"
    if isinstance(piece, Links):
        return "\n".join(f"- [{label}]({_target(target)})" for label, target in piece.links)
    raise TypeError(f"not a report piece: {type(piece).__name__}")


def _cell(value) -> str:
    """A pipe-table cell: `|` escaped, a Strong cell in ** **."""
    text = cell_text(value).replace("|", "\\|")
    return f"**{text}**" if isinstance(value, Strong) else text


def _target(path: str) -> str:
    """A link target that markdown reads whole (a space or a parenthesis would end it), percent-encoded."""
    return urllib.parse.quote(path)
