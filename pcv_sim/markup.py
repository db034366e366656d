"""The pieces of the reports in Markdown and HTML: tables, links relative to the report, images
embedded in the page.

Each table cell is escaped for its format (a `|` in Markdown, `<`, `>`, `&` and quotes in HTML),
so a value can never break its table.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path

__all__ = ["html_table", "markdown_table", "png_source", "relative_link"]


def markdown_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table: a header row, its rule, one line a row."""
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(out)


def html_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An HTML table with a head and a body."""
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def relative_link(path: Path, base: Path) -> str:
    """`path` as a report in folder `base` links it: relative when it lies below `base`, else absolute."""
    try:
        return path.resolve().relative_to(base.resolve()).as_posix()
    except ValueError:
        return path.resolve().as_posix()


def png_source(png: bytes) -> str:
    """An `<img>` source that carries the PNG itself (a data URI), so the page stands alone."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")
