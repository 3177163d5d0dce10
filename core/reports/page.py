"""One self-contained HTML page: plotly.js embedded once from the installed plotly package, each
figure a ``<div>`` with its data, tables as plain HTML.

Why embedded and not a CDN link or a file beside the page: a line PC has no internet, a report is
mailed or copied to a share, and it must open anywhere with nothing next to it.  plotly.js is about
4.8 MB of the file; the page asks nothing of the network.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence
from functools import cache
from pathlib import Path

import plotly.graph_objects as go
from plotly.offline import get_plotlyjs

STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #1d1d1f; }
h1 { margin-bottom: 0.2em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.92em; }
th, td { border: 1px solid #ddd; padding: 0.25em 0.6em; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.verdict { display: inline-block; padding: 0.2em 0.8em; border-radius: 0.3em; color: white; font-weight: bold; }
.pass { background: #1a7f37; } .fail { background: #cf222e; } .error, .aborted, .incomplete { background: #9a6700; }
.review { background: #d4a72c; color: black; } tr.fail td { background: #ffebe9; } tr.review td { background: #fff8c5; }
.note { color: #57606a; }
"""


@cache
def _plotly_js() -> str:
    return get_plotlyjs()


def figure_html(fig: go.Figure, div_id: str) -> str:
    return fig.to_html(full_html=False, include_plotlyjs=False, div_id=div_id,
                       config={"displaylogo": False, "responsive": True})


def table(header: Sequence[str] | None, rows: Iterable[Sequence[object]], row_class: Sequence[str] | None = None,
          numeric: Sequence[int] = ()) -> str:
    """An HTML table; every cell escaped.  ``numeric``: columns aligned right.  ``header`` None: no
    header row (a table of named facts needs none, and an empty one shows as a blank first row)."""
    head = "" if header is None else (
        "<thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr></thead>")
    out = ["<table>" + head + "<tbody>"]
    for i, row in enumerate(rows):
        css = f' class="{row_class[i]}"' if row_class and row_class[i] else ""
        cells = "".join(f"<td{' class=num' if j in numeric else ''}>{html.escape(str(c))}</td>"
                        for j, c in enumerate(row))
        out.append(f"<tr{css}>{cells}</tr>")
    out.append("</tbody></table>")
    return "".join(out)


PLOTLY_FILE = "plotly.min.js"


def shared_plotly(folder: Path) -> str:
    """plotly.js as one file in ``folder`` (written once), for pages written there by the hundred:
    inline, each unit report carries its 3.6 MB again.  Returns the file's name for ``write_page``."""
    target = folder / PLOTLY_FILE
    if not target.is_file() or target.stat().st_size != len(_plotly_js().encode()):
        folder.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".part")
        tmp.write_text(_plotly_js(), encoding="utf-8")
        tmp.replace(target)
    return PLOTLY_FILE


def write_page(path: Path, title: str, sections: Sequence[str], plotly_src: str | None = None) -> Path:
    """The page: head with the style and plotly.js, then the sections' HTML in order.  ``plotly_src``:
    plotly.js from that file beside the page (:func:`shared_plotly`) instead of inline."""
    path.parent.mkdir(parents=True, exist_ok=True)
    script = (f"<script src='{html.escape(plotly_src)}'></script>" if plotly_src
              else f"<script>{_plotly_js()}</script>")
    doc = (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{html.escape(title)}</title>"
           f"<meta name=viewport content='width=device-width, initial-scale=1'><style>{STYLE}</style>"
           f"{script}</head><body>{''.join(sections)}</body></html>")
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(doc, encoding="utf-8")
    tmp.replace(path)  # a half-written report is never left under the final name
    return path
