"""Assemble figures, tables and text into ONE self-contained HTML page (PNG figures inlined as base64, CSS inline,
no scripts, no external links), so a report can be mailed or opened offline."""

from __future__ import annotations

import base64
import datetime as _dt
import html as _html
from dataclasses import dataclass, field
from typing import Any, Sequence

from radarcal.report._common import figure_to_png

__all__ = ["Table", "Section", "render_html", "png_data_uri", "inline_pngs"]


@dataclass
class Table:
    """A plain table: ``columns`` header and ``rows`` of cells (any value; formatted with ``str``)."""

    columns: Sequence[str]
    rows: Sequence[Sequence[Any]]
    caption: str = ""


@dataclass
class Section:
    """One report section: a title and items in order. An item is a matplotlib Figure, ``(Figure, caption)``,
    a :class:`Table`, or a string (a paragraph of text)."""

    title: str
    items: list = field(default_factory=list)

    def add(self, item: Any, caption: str = "") -> "Section":
        self.items.append((item, caption) if caption else item)
        return self


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:0;background:#f6f7f9;color:#1d2330}
header{background:#1d2330;color:#fff;padding:16px 28px}header h1{margin:0;font-size:22px}header p{margin:4px 0 0;color:#c8cdd8;font-size:13px}
nav{padding:10px 28px;background:#fff;border-bottom:1px solid #dde1e8;font-size:14px}nav a{margin-right:16px;color:#2458c6;text-decoration:none}
main{padding:8px 28px 40px}section{background:#fff;border:1px solid #dde1e8;border-radius:6px;margin:18px 0;padding:12px 20px}
h2{font-size:18px;margin:6px 0 12px}figure{margin:10px 0 18px}figure img{max-width:100%;height:auto;border:1px solid #e3e6ec}
figcaption{font-size:13px;color:#4a5264;margin-top:4px}table{border-collapse:collapse;margin:8px 0 16px;font-size:13px}
th,td{border:1px solid #d3d8e0;padding:3px 10px;text-align:right}th{background:#eef1f6}td:first-child,th:first-child{text-align:left}
caption{caption-side:top;text-align:left;font-weight:600;padding-bottom:4px}p{font-size:14px;line-height:1.45}
"""


def png_data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _item_html(item: Any, dpi: int) -> str:
    caption = ""
    if isinstance(item, tuple) and len(item) == 2:
        item, caption = item
    if isinstance(item, Table):
        head = "".join(f"<th>{_html.escape(str(c))}</th>" for c in item.columns)
        body = "".join("<tr>" + "".join(f"<td>{_html.escape(str(c))}</td>" for c in row) + "</tr>" for row in item.rows)
        cap = f"<caption>{_html.escape(item.caption or caption)}</caption>" if (item.caption or caption) else ""
        return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    if isinstance(item, str):
        return f"<p>{_html.escape(item)}</p>"
    if hasattr(item, "savefig"):
        png = figure_to_png(item, dpi=dpi)
        w_px = int(round(item.get_figwidth() * 96))  # display size independent of the resolution
        alt = _html.escape(caption or _figure_title(item) or "figure")
        cap = f"<figcaption>{_html.escape(caption)}</figcaption>" if caption else ""
        return f'<figure><img alt="{alt}" width="{w_px}" src="{png_data_uri(png)}">{cap}</figure>'
    raise TypeError(f"cannot put a {type(item).__name__} into the report")


def _figure_title(fig) -> str:
    if getattr(fig, "_suptitle", None) is not None:
        return fig._suptitle.get_text()
    for ax in fig.axes:
        if ax.get_title():
            return ax.get_title()
    return ""


def _anchor(i: int) -> str:
    return f"s{i}"


def render_html(title: str, sections: Sequence[Section], subtitle: str = "", dpi: int = 96) -> str:
    """The whole report as one HTML string (UTF-8)."""
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    sub = _html.escape(subtitle + (" · " if subtitle else "") + f"generated {now}")
    nav = "".join(f'<a href="#{_anchor(i)}">{_html.escape(s.title)}</a>' for i, s in enumerate(sections))
    parts = []
    for i, s in enumerate(sections):
        inner = "\n".join(_item_html(it, dpi) for it in s.items) or "<p>(nothing to show)</p>"
        parts.append(f'<section id="{_anchor(i)}"><h2>{_html.escape(s.title)}</h2>\n{inner}\n</section>')
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{_html.escape(title)}</title><style>{_CSS}</style></head>\n<body>"
        f"<header><h1>{_html.escape(title)}</h1><p>{sub}</p></header><nav>{nav}</nav><main>\n"
        + "\n".join(parts)
        + "\n</main></body></html>\n"
    )


def inline_pngs(html_text: str) -> list[bytes]:
    """The PNG images inlined in a report (for checks)."""
    import re

    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html_text)]
