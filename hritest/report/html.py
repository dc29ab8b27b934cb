"""A report as a small document tree, rendered to one self-contained HTML page or to Markdown.

The HTML page embeds its figures as base64 PNG and its style sheet, so it opens from disk and
can be mailed or attached to CI as one file. The Markdown refers to the figures as PNG files
written beside it. Every piece of text goes through :func:`html.escape`.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Link:
    text: str
    href: str


@dataclass(frozen=True)
class Badge:
    """A short verdict, green when ``ok`` and red when not."""

    text: str
    ok: bool


@dataclass(frozen=True)
class Code:
    """Monospaced text (scenario parameters, paths)."""

    text: str


Cell = str | Link | Badge | Code


@dataclass(frozen=True)
class Table:
    headers: Sequence[str]
    rows: Sequence[Sequence[Cell]]
    caption: str = ""


@dataclass(frozen=True)
class Figure:
    """A PNG; ``name`` is its file name beside the Markdown."""

    name: str
    png: bytes
    alt: str
    caption: str = ""


@dataclass(frozen=True)
class Text:
    text: str
    note: bool = False  # a highlighted call-out rather than a paragraph


@dataclass(frozen=True)
class Details:
    """Blocks folded away behind a summary line (the full progress log, for instance)."""

    summary: str
    blocks: Sequence[Block]


Block = Table | Figure | Text | Details


@dataclass(frozen=True)
class Section:
    title: str
    blocks: Sequence[Block]


@dataclass(frozen=True)
class Document:
    title: str
    subtitle: str
    sections: Sequence[Section] = field(default_factory=tuple)

    def figures(self) -> list[Figure]:
        """Every figure in the document, for writing beside the Markdown."""
        found: list[Figure] = []

        def walk(blocks: Sequence[Block]) -> None:
            for block in blocks:
                if isinstance(block, Figure):
                    found.append(block)
                elif isinstance(block, Details):
                    walk(block.blocks)

        for section in self.sections:
            walk(section.blocks)
        return found


# --- HTML ------------------------------------------------------------------------------------

_STYLE = """
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1d1d1f;
       margin: 0; background: #fafafa; }
main { max-width: 1180px; margin: 0 auto; padding: 24px 32px 48px; background: #fff; }
h1 { font-size: 26px; margin: 0 0 4px; }
.subtitle { color: #555; margin: 0 0 20px; }
h2 { font-size: 19px; border-bottom: 2px solid #e4e4e8; padding-bottom: 4px; margin: 32px 0 12px; }
table { border-collapse: collapse; margin: 8px 0 16px; font-size: 13.5px; }
caption { text-align: left; color: #555; padding: 0 0 4px; font-size: 13px; }
th, td { border: 1px solid #dcdce0; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #f0f0f4; font-weight: 600; }
tbody tr:nth-child(even) { background: #f8f8fb; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
code { font: 12px/1.35 ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; }
figure { margin: 8px 0 20px; }
figure img { max-width: 100%; height: auto; border: 1px solid #e4e4e8; }
figcaption { color: #555; font-size: 13px; margin-top: 4px; max-width: 900px; }
.badge { display: inline-block; padding: 1px 7px; border-radius: 9px; font-size: 12px; white-space: nowrap; }
.ok { background: #dff3e4; color: #17652d; }
.bad { background: #fde2e1; color: #9b1c17; }
.note { background: #fff7d6; border-left: 4px solid #e8b400; padding: 8px 12px; }
details { margin: 8px 0 16px; }
summary { cursor: pointer; color: #1f4e79; }
a { color: #1f5fa8; }
"""


def to_html(doc: Document) -> str:
    """The whole page, figures and style included."""
    body = "\n".join(_section_html(s) for s in doc.sections)
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{_e(doc.title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n<main>\n"
        f'<h1>{_e(doc.title)}</h1>\n<p class="subtitle">{_e(doc.subtitle)}</p>\n{body}\n'
        "</main>\n</body>\n</html>\n"
    )


def _section_html(section: Section) -> str:
    return f"<section>\n<h2>{_e(section.title)}</h2>\n" + "\n".join(map(_block_html, section.blocks)) + "\n</section>"


def _block_html(block: Block) -> str:
    if isinstance(block, Text):
        return f'<p class="note">{_e(block.text)}</p>' if block.note else f"<p>{_e(block.text)}</p>"
    if isinstance(block, Figure):
        data = base64.b64encode(block.png).decode("ascii")
        caption = f"<figcaption>{_e(block.caption)}</figcaption>" if block.caption else ""
        return f'<figure><img alt="{_e(block.alt)}" src="data:image/png;base64,{data}">{caption}</figure>'
    if isinstance(block, Details):
        inner = "\n".join(map(_block_html, block.blocks))
        return f"<details><summary>{_e(block.summary)}</summary>\n{inner}\n</details>"
    caption = f"<caption>{_e(block.caption)}</caption>" if block.caption else ""
    head = "".join(f"<th>{_e(h)}</th>" for h in block.headers)
    head = f"<thead><tr>{head}</tr></thead>" if any(block.headers) else ""  # a key-value table has none
    rows = "\n".join("<tr>" + "".join(_cell_html(c) for c in row) + "</tr>" for row in block.rows)
    return f"<table>{caption}{head}\n<tbody>\n{rows}\n</tbody></table>"


def _cell_html(cell: Cell) -> str:
    if isinstance(cell, Link):
        return f'<td><a href="{_e(cell.href)}">{_e(cell.text)}</a></td>'
    if isinstance(cell, Badge):
        return f'<td><span class="badge {"ok" if cell.ok else "bad"}">{_e(cell.text)}</span></td>'
    if isinstance(cell, Code):
        return f"<td><code>{_e(cell.text)}</code></td>"
    return f'<td class="num">{_e(cell)}</td>' if _numeric(cell) else f"<td>{_e(cell)}</td>"


def _numeric(text: str) -> bool:
    try:
        float(text.replace(",", "").rstrip("%"))
    except ValueError:
        return False
    return True


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


# --- Markdown --------------------------------------------------------------------------------


def to_markdown(doc: Document) -> str:
    """The same document as GitHub-flavoured Markdown; figures are referenced by file name."""
    parts = [f"# {doc.title}", "", doc.subtitle, ""]
    for section in doc.sections:
        parts += [f"## {section.title}", ""]
        for block in section.blocks:
            parts += _block_md(block)
    return "\n".join(parts).rstrip() + "\n"


def _block_md(block: Block) -> list[str]:
    if isinstance(block, Text):
        return [f"> {block.text}" if block.note else block.text, ""]
    if isinstance(block, Figure):
        return [f"![{block.alt}]({block.name})", "", *([f"*{block.caption}*", ""] if block.caption else [])]
    if isinstance(block, Details):
        lines = [f"<details><summary>{_e(block.summary)}</summary>", ""]
        for inner in block.blocks:
            lines += _block_md(inner)
        return [*lines, "</details>", ""]
    lines = [f"*{block.caption}*", ""] if block.caption else []
    lines.append("| " + " | ".join(_md_escape(h) for h in block.headers) + " |")
    lines.append("|" + "---|" * len(block.headers))
    for row in block.rows:
        lines.append("| " + " | ".join(_cell_md(c) for c in row) + " |")
    return [*lines, ""]


def _cell_md(cell: Cell) -> str:
    if isinstance(cell, Link):
        return f"[{_md_escape(cell.text)}]({cell.href})"
    if isinstance(cell, Badge):
        return ("✓ " if cell.ok else "✗ ") + _md_escape(cell.text)
    if isinstance(cell, Code):
        return f"`{cell.text.replace('`', '')}`"
    return _md_escape(cell)


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")
