"""The diagnosis report as a web page: headings, paragraphs, real tables and figures.

The report is written once, as a list of lines and tables (:func:`sim2real.report.document`);
``report.md`` joins them as Markdown and this module renders the same list through a Jinja2
template (autoescaped), so a browser shows HTML tables instead of Markdown source. Only the
report's own conventions are read: ``#``/``##``/``###`` headings, ``- `` list items,
``![name](file)`` figures, `` `code` `` and ``**bold**`` inside text, blank lines between
paragraphs, and :class:`models.report.MarkdownTable` items for tables.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from jinja2 import Environment

from models.report import MarkdownTable

__all__ = ["blocks", "render_html"]

_INLINE = re.compile(r"(`[^`]+`|\*\*[^*]+\*\*)")
_FIGURE = re.compile(r"^!\[([^\]]*)\]\(([^)]+)\)$")


def _spans(text: str) -> list[tuple[str, str]]:
    """``text`` as (kind, text) spans: ``code``, ``strong`` or ``text``."""
    out = []
    for piece in _INLINE.split(text):
        if not piece:
            continue
        if piece.startswith("`") and piece.endswith("`"):
            out.append(("code", piece[1:-1]))
        elif piece.startswith("**") and piece.endswith("**"):
            out.append(("strong", piece[2:-2]))
        else:
            out.append(("text", piece))
    return out


def blocks(items: Iterable) -> list[dict]:
    """The page's blocks from the report's lines and tables, in order."""
    out: list[dict] = []
    paragraph: list[str] = []
    bullets: list[str] = []

    def flush() -> None:
        if paragraph:
            out.append({"kind": "p", "spans": _spans(" ".join(paragraph))})
            paragraph.clear()
        if bullets:
            out.append({"kind": "ul", "items": [_spans(b) for b in bullets]})
            bullets.clear()

    for item in items:
        if isinstance(item, MarkdownTable):
            flush()
            out.append(
                {
                    "kind": "table",
                    "header": [_spans(str(h)) for h in item.header],
                    "rows": [[_spans(str(c)) for c in row] for row in item.rows],
                }
            )
            continue
        for line in str(item).split("\n"):
            stripped = line.strip()
            heading = re.match(r"^(#{1,3}) (.*)$", stripped)
            figure = _FIGURE.match(stripped)
            if not stripped:
                flush()
            elif heading:
                flush()
                out.append({"kind": f"h{len(heading.group(1))}", "text": heading.group(2)})
            elif figure:
                flush()
                out.append({"kind": "figure", "alt": figure.group(1), "src": figure.group(2)})
            elif stripped.startswith("- "):
                if paragraph:
                    flush()
                bullets.append(stripped[2:])
            elif bullets and line.startswith("  "):  # a list item's continuation
                bullets[-1] += " " + stripped
            else:
                if bullets:
                    flush()
                paragraph.append(stripped)
    flush()
    first = next((b for b in out if b["kind"] == "p"), None)
    if first is not None:
        first["lead"] = True
    return out


_TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{{ title }}</title>
<style>
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
line-height:1.45;color:#222;overflow-wrap:anywhere}
.answer{font-size:1.1em;background:#f3f6fa;border-left:4px solid #3b6ea5;padding:.8em 1em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.88em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:left;vertical-align:top}
th{background:#eef1f5} tr:nth-child(even) td{background:#fafafa}
img{max-width:100%} code{background:#f2f2f2;padding:0 .2em}
</style></head><body>
{%- macro spans(items) -%}
{%- for kind, text in items -%}
{%- if kind == "code" %}<code>{{ text }}</code>
{%- elif kind == "strong" %}<strong>{{ text }}</strong>
{%- else %}{{ text }}{% endif -%}
{%- endfor -%}
{%- endmacro %}
{% for block in blocks %}
{%- if block.kind in ("h1", "h2", "h3") %}<{{ block.kind }}>{{ block.text }}</{{ block.kind }}>
{%- elif block.kind == "p" -%}
<p{% if block.lead %} class="answer"{% endif %}>{{ spans(block.spans) }}</p>
{%- elif block.kind == "ul" %}<ul>
{%- for item in block["items"] %}<li>{{ spans(item) }}</li>{% endfor %}</ul>
{%- elif block.kind == "figure" -%}
<figure><img src="{{ block.src }}" alt="{{ block.alt }}"></figure>
{%- elif block.kind == "table" %}<table><thead><tr>
{%- for cell in block.header %}<th>{{ spans(cell) }}</th>{% endfor %}</tr></thead><tbody>
{% for row in block.rows %}<tr>
{%- for cell in row %}<td>{{ spans(cell) }}</td>{% endfor %}</tr>
{% endfor %}</tbody></table>
{%- endif %}
{% endfor %}</body></html>
"""


def render_html(items: Iterable, title: str) -> str:
    """The page of the report's lines and tables; its first paragraph is styled as the answer."""
    environment = Environment(autoescape=True, keep_trailing_newline=True)
    return environment.from_string(_TEMPLATE).render(blocks=blocks(items), title=title)
