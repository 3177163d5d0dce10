"""One self-contained HTML page: plotly.js embedded once from the installed plotly package, each
figure a ``<div>`` with its data, tables as plain HTML.

Why embedded and not a CDN link or a file beside the page: a line PC has no internet, a report is
mailed or copied to a share, and it must open anywhere with nothing next to it.  plotly.js is about
4.8 MB of the file; the page asks nothing of the network.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Sequence
from functools import cache
from pathlib import Path
from typing import Any

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


PLOTLY_DEFAULT_HEIGHT = 450  # px: what plotly.js draws a figure without a layout height at


def typed_array(values: Any) -> dict[str, str]:
    """Numbers as plotly.js's typed-array spec (little-endian float64, base64), as plotly's own figure
    objects send them: 12 characters a number where decimal text takes up to 24, and the browser decodes
    them without parsing each."""
    import numpy as np

    packed = np.ascontiguousarray(values, dtype="<f8")
    return {"dtype": "f8", "bdata": base64.b64encode(packed.tobytes()).decode("ascii")}


@cache
def plain_layout() -> dict[str, Any]:
    """A figure's layout as plotly's objects start it (its default template: the look of every chart), for
    figures built as plain JSON."""
    return go.Figure().to_plotly_json()["layout"]


def figure_html(fig: go.Figure | dict[str, Any], div_id: str) -> str:
    """The figure's ``<div>``, sized as it will be drawn, and its data beside it as JSON; :data:`DRAW_SCRIPT`
    (added once by :func:`write_page`) draws it.  Why not plotly's own ``to_html``: its script draws each
    figure where the page is read, so a page of a dozen charts showed nothing until all were drawn
    (1.5 s of the process page); here the charts in view are drawn first, the page painted between two."""
    from plotly.io.json import to_json_plotly

    figure = fig if isinstance(fig, dict) else fig.to_plotly_json()  # a dict: the figure's JSON already
    height = figure.get("layout", {}).get("height") or PLOTLY_DEFAULT_HEIGHT
    spec = to_json_plotly({"data": figure.get("data", []), "layout": figure.get("layout", {}),
                           "config": {"displaylogo": False, "responsive": True}})
    spec = spec.replace("</", "<\\/")  # inside a script element "</" would end it; "<\\/" is the same JSON
    return (f'<div id="{html.escape(div_id)}" class="plotly-graph-div plot-pending" '
            f'style="height:{int(height)}px; width:100%;"></div>'
            f'<script type="application/json" data-plot="{html.escape(div_id)}">{spec}</script>')


# Draws every figure of :func:`figure_html` on the page, one per task after a frame, so the page is painted
# and answers between two charts: each time the first still undrawn in view (the reader may have scrolled, or
# come by a link to a chart far down), else the first undrawn in page order.  Each chart's div loses
# ``plot-pending`` and sends a bubbling ``plotted`` event once drawn (a page's own handlers attach then); one
# that cannot be drawn says so in its place.
DRAW_SCRIPT = """<script>
(function () {
  var pending = Array.prototype.slice.call(document.querySelectorAll('script[data-plot]'));
  function inView(spec) {
    var box = document.getElementById(spec.dataset.plot).getBoundingClientRect();
    return box.bottom > 0 && box.top < window.innerHeight;
  }
  function later() { requestAnimationFrame(function () { setTimeout(drawNext, 0); }); }
  function drawNext() {
    var spec = pending.filter(inView)[0] || pending[0];
    if (!spec) { return; }
    pending.splice(pending.indexOf(spec), 1);
    var div = document.getElementById(spec.dataset.plot);
    Promise.resolve().then(function () {
      var figure = JSON.parse(spec.textContent);
      return Plotly.newPlot(div, figure.data, figure.layout, figure.config);
    }).then(function () {
      div.classList.remove('plot-pending');
      div.dispatchEvent(new CustomEvent('plotted', {bubbles: true}));
      later();
    }, function (error) {  // one chart that cannot be drawn says so and leaves the others to be drawn
      div.classList.remove('plot-pending');
      div.classList.add('plot-failed');
      div.textContent = 'this chart could not be drawn: ' + error;
      later();
    });
  }
  later();  // the page's words are painted first, then each chart
})();
</script>"""


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


def page_head(title: str, plotly_src: str | None = None) -> str:
    """A page's beginning up to ``</head>``: its style and plotly.js (inline, or from ``plotly_src``).  A
    server may send it before the page's charts are built: the browser fetches and compiles plotly.js
    meanwhile."""
    script = (f"<script src='{html.escape(plotly_src)}'></script>" if plotly_src
              else f"<script>{_plotly_js()}</script>")
    return (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{html.escape(title)}</title>"
            f"<meta name=viewport content='width=device-width, initial-scale=1'><style>{STYLE}</style>"
            f"{script}</head>")


def page_body(sections: Sequence[str]) -> str:
    """What goes between ``<body>`` and ``</body>``: the sections' HTML in order, and the script that draws
    their charts where there are any (a server sends it after :func:`page_head`)."""
    doc_body = "".join(sections)
    return doc_body + (DRAW_SCRIPT if "data-plot=" in doc_body else "")


def write_page(path: Path, title: str, sections: Sequence[str], plotly_src: str | None = None) -> Path:
    """The page: head with the style and plotly.js, then the sections' HTML in order.  ``plotly_src``:
    plotly.js from that file beside the page (:func:`shared_plotly`) instead of inline."""
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = f"{page_head(title, plotly_src)}<body>{page_body(sections)}</body></html>"
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(doc, encoding="utf-8")
    tmp.replace(path)  # a half-written report is never left under the final name
    return path
