"""Reports a person opens: Markdown, and the same page as standalone HTML for a browser."""

from __future__ import annotations

import html
import os
from pathlib import Path

_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:60rem;margin:2rem auto;padding:0 1rem;line-height:1.45}"
    "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.25rem .6rem}img{max-width:100%}"
)


def write_report(path: str | os.PathLike, markdown: str, *, title: str) -> tuple[Path, Path]:
    """Write `markdown` to `path` (report.md) and its HTML rendering beside it (report.html),
    each under a temporary name first; image links stay relative, so both open in place."""
    from markdown_it import MarkdownIt

    path = Path(path)
    body = MarkdownIt("commonmark").enable("table").render(markdown)
    page = (
        f'<!doctype html>\n<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{_STYLE}</style></head>\n<body>\n{body}</body></html>\n"
    )
    written = []
    for target, text in ((path, markdown), (path.with_suffix(".html"), page)):
        temporary = target.with_name(f".{target.name}.partial")
        temporary.write_text(text)
        os.replace(temporary, target)
        written.append(target)
    return written[0], written[1]
