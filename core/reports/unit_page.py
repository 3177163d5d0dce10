"""The unit report: one HTML page a person opens to see what happened to one unit.

Top: identity and verdict.  Then every measurement with its limits and verdict (review flags
marked, with the process-review reason), the corrected-magnitude residual per sample (mean, std,
peak-to-peak), raw and corrected samples in 3D with the fitted ellipsoid and the sphere of the
field, the coverage sphere with its bins, every acquisition attempt and why it was not used, the
parameters before / written / echoed / read back after the power cycle, and the field reference.

Built from the stored record (``reading.find_run`` and the attempts' raw arrays), so a report
written at the station and one written a year later from the server are the same page.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import plotly.graph_objects as go

from magline.core.fit.coverage import bin_index, covered_bins, fibonacci_sphere
from magline.core.reports.page import figure_html, table, write_page
from magline.core.results.record_words import (
    compass_rows,
    interference_rows,
    mounting_rows,
    persistence_rows,
    unit_facts,
    value_words,
)
from magline.core.text import FLOAT32_RULE, fmt, param_text, percent, seconds

if TYPE_CHECKING:
    from magline.core.fit.samples_csv import RawSamples

MAX_POINTS = 3000  # per 3D trace: keeps the page small and the browser quick


def _verdict(value: str | None) -> str:
    v = str(value or "—")
    return f"<span class='verdict {html.escape(v)}'>{html.escape(v.upper())}</span>"


def _identity(run: dict[str, Any]) -> str:
    unit = run.get("unit_info") or {}
    review = " <span class='verdict review'>REVIEW</span>" if run.get("review") else ""
    facts = [("run", f"{run['id']} ({run['run_uuid']})"), ("part", run["part"]),
             ("station", f"{run['station_id']} (line {run['line']})"), ("operator", run.get("operator") or "—"),
             ("started", run.get("started") or "—"), ("finished", run.get("finished") or "—"),
             ("magline", run.get("software_version") or "—"), ("limit set", run.get("limit_hash") or "—"),
             ("station file", run.get("station_hash") or "—"),
             ("field reference", fmt(run.get("reference_field_ut"), "µT"))]
    facts += unit_facts(unit)
    out = [f"<h1>{html.escape(run['serial'])} {_verdict(run['verdict'])}{review}</h1>"]
    if run.get("cause"):
        out.append(f"<p><b>cause:</b> {html.escape(run['cause'])}</p>")
    for key, title in (("left_changed", "NOT RESTORED"), ("unverified_params", "UNVERIFIED")):
        if run.get(key):
            out.append(f"<p><b>{title}:</b> {html.escape(value_words(run[key]))} — re-test the unit</p>")
    out.append(table(None, [(k, v) for k, v in facts]))  # facts by name: no header row
    compasses = compass_rows(unit)
    if compasses:
        out += ["<h2>Magnetometers</h2>", table(("compass", "sensor", "device id", "orientation"), compasses)]
    return "".join(out)


def _measurements(run: dict[str, Any]) -> str:
    flags = {f["name"]: f["reason"] for f in run.get("review") or []}
    rows, classes = [], []
    for m in run["measurements"]:
        if m["kind"] != "numeric":
            continue
        limit = f"[{fmt(m['low'])}, {fmt(m['high'])}]" if m["low"] is not None or m["high"] is not None else "no limit"
        note = flags.get(m["name"], "within the marginal band" if m["verdict"] == "review" else "")
        rows.append((m["name"], fmt(m["value"], m["unit"] or ""), limit, m["verdict"], note))
        classes.append(m["verdict"] if m["verdict"] in ("fail", "review") else "")
    out = ["<h2>Measurements</h2>", table(("measurement", "value", "limits", "verdict", "review"), rows, classes,
                                          numeric=(1,))]
    if run.get("review_note"):
        out.append(f"<p class=note>{html.escape(run['review_note'])}</p>")
    return "".join(out)


def _residual_charts(run: dict[str, Any]) -> str:
    """One residual chart per magnetometer (the primary's ``residual_ut``, then ``mag2.residual_ut`` …)."""
    arrays = [m for m in run["measurements"] if m["kind"] == "array" and m["data"]
              and (m["name"] == "residual_ut" or m["name"].endswith(".residual_ut"))]
    if not arrays:
        return "<h2>Residual</h2><p class=note>no fit: no residual to show</p>"
    labels = {(s.get("prefix") or "mag1"): f"{s.get('label', 'magnetometer')} ({s.get('device_id')})"
              for s in (run.get("unit_info") or {}).get("magnetometers", [])}
    out = []
    for m in arrays:
        prefix = m["name"].removesuffix("residual_ut").rstrip(".") or "mag1"
        title = f"Residual — {labels[prefix]}" if len(arrays) > 1 and prefix in labels else "Residual"
        plot_id = "residual" if prefix == "mag1" else f"residual-{prefix}"
        out.append(_residual_chart(json.loads(m["data"]), title, plot_id))
    return "".join(out) + _mounting(run)


def _mounting(run: dict[str, Any]) -> str:
    """Each sensor's mounting and each pair's agreement, as the validate phase judged them; then each
    compass's current interference where it was swept."""
    rows = mounting_rows(run.get("unit_info"))
    out = "<h2>Mounting</h2>" + table(["sensor / pair", "found", "misalignment", "inclination"], rows) if rows else ""
    current = interference_rows(run.get("unit_info"))
    if current:
        # the notes are sentences, not a compass's figures: under the table, not squeezed into its second column
        notes = [row[1] for row in current if row[0] == "note"]
        out += "<h2>Current interference</h2>" + table(["compass", "field per amp", "at the top current",
                                                         "linearity, return to zero"],
                                                        [row for row in current if row[0] != "note"])
        out += "".join(f"<p class=note>{html.escape(note)}</p>" for note in notes)
    return out


def _residual_chart(residual: list[float], title: str, name: str) -> str:
    r = np.asarray(residual, dtype=float)
    stats = f"mean {fmt(float(r.mean()), 'µT')}, std {fmt(float(r.std(ddof=1)), 'µT')}, " \
            f"p2p {fmt(float(np.ptp(r)), 'µT')}"
    fig = go.Figure(go.Scatter(x=np.arange(1, r.size + 1), y=r, mode="markers", marker={"size": 4},
                               name="residual", hovertemplate="sample %{x}<br>%{y:.3f} µT<extra></extra>"))
    fig.add_hline(y=float(r.mean()), line={"color": "#0969da", "width": 1})
    for k in (-1, 1):
        fig.add_hline(y=float(r.mean() + k * r.std(ddof=1)), line={"color": "#0969da", "dash": "dash", "width": 1})
    fig.update_layout(title=f"|m_cal| − field per sample: {stats}", height=360, xaxis_title="sample",
                      yaxis_title="µT", margin={"l": 60, "r": 30, "t": 50, "b": 40})
    return f"<h2>{html.escape(title)}</h2>" + figure_html(fig, name)


def _sphere_mesh(n: int = 24) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 2 * n), np.linspace(0, np.pi, n))
    return np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)


def _thin(points: np.ndarray) -> np.ndarray:
    step = max(1, len(points) // MAX_POINTS)
    return points[::step]


def _surface(points: np.ndarray, name: str, colour: str) -> go.Surface:
    return go.Surface(x=points[..., 0], y=points[..., 1], z=points[..., 2], opacity=0.18, showscale=False,
                      colorscale=[[0, colour], [1, colour]], name=name, hoverinfo="skip")


def _scatter(points: np.ndarray, name: str, colour: str) -> go.Scatter3d:
    p = _thin(points)
    return go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", name=name,
                        marker={"size": 2, "color": colour})


def _samples_3d(cal: dict[str, Any], raw: RawSamples, div_id: str = "samples3d") -> str:
    h = np.asarray(cal["hard_iron_ut"], dtype=float)
    s = np.asarray(cal["soft_iron"], dtype=float)
    field = float(cal["field_ut"])
    corrected = (raw.mag_ut - h) @ s.T
    mesh = _sphere_mesh() * field
    ellipsoid = mesh @ np.linalg.inv(s).T + h  # the raw readings' surface: S·(m − h) on the sphere
    fig = go.Figure([_scatter(raw.mag_ut, "raw", "#cf222e"), _surface(ellipsoid, "fitted ellipsoid", "#cf222e"),
                     _scatter(corrected, "corrected", "#1a7f37"), _surface(mesh, f"sphere {field:.1f} µT", "#1a7f37")])
    fig.update_layout(title="raw samples on the fitted ellipsoid, corrected samples on the field's sphere (µT)",
                      height=560, scene={"aspectmode": "data"}, margin={"l": 0, "r": 0, "t": 40, "b": 0})
    return figure_html(fig, div_id)


def _coverage_3d(cal: dict[str, Any], raw: RawSamples) -> str:
    """The direction bins of the accepted attempt, found as its judged coverage was (the same function,
    the same bins): the picture and the figure in the attempts table are one number."""
    bins = int((cal.get("coverage") or {}).get("bins") or 100)
    centres = fibonacci_sphere(bins)
    hit = np.bincount(bin_index(raw.mag_ut - np.asarray(cal["hard_iron_ut"]), bins), minlength=bins)
    covered = np.zeros(bins, bool)
    covered[covered_bins(raw.mag_ut, bins)] = True
    mesh = _sphere_mesh() * 0.97
    fig = go.Figure([_surface(mesh, "sphere", "#d0d7de"),
                     go.Scatter3d(x=centres[covered, 0], y=centres[covered, 1], z=centres[covered, 2], mode="markers",
                                  name=f"covered bins ({covered.sum()})",
                                  text=[f"{n} samples" if n else "covered" for n in hit[covered]],
                                  marker={"size": 7, "color": "#1a7f37"}),
                     go.Scatter3d(x=centres[~covered, 0], y=centres[~covered, 1], z=centres[~covered, 2],
                                  mode="markers", name=f"empty bins ({(~covered).sum()})",
                                  # a circle: WebGL draws 3D markers as font glyphs, and Chromium's fonts
                                  # lack the "x" one (tofu boxes where the missing bins should show)
                                  marker={"size": 7, "color": "#cf222e", "symbol": "circle"})])
    fig.update_layout(title=f"coverage: {covered.sum()} of {bins} direction bins ({percent(covered.mean())})",
                      height=480, scene={"aspectmode": "cube"}, margin={"l": 0, "r": 0, "t": 40, "b": 0})
    return figure_html(fig, "coverage3d")


def compass_names(run: dict[str, Any]) -> dict[int, str]:
    """Device id → the compass's name in the record (``mag1`` the primary, ``mag2``…)."""
    return {int(row[2]): row[0] for row in compass_rows(run.get("unit_info")) if row[2].isdigit()}


def other_compasses(run: dict[str, Any], attempt: dict[str, Any], bins: int) -> str:
    """The other compasses' readings in an attempt and their coverage, counted as the primary's is
    (the same bins, the same function on their raw readings)."""
    names = compass_names(run)
    return "; ".join(f"{names.get(device, device)}: {len(raw.mag_ut)} readings, "
                     f"{percent(len(covered_bins(raw.mag_ut, bins)) / bins)}"
                     for device, raw in (attempt.get("others") or {}).items()) or "—"


def _attempts(run: dict[str, Any]) -> str:
    bins = int(((run.get("calibration") or {}).get("coverage") or {}).get("bins") or 100)
    several = any(a.get("others") for a in run["attempts"])
    rows = [(a["attempt"], a["samples"], percent(a["coverage"]), percent(a["target"]),
             "accepted" if a["accepted"] else (a.get("refused") or "superseded"), a.get("repeats") or 0,
             fmt(a.get("sensor_rate_hz"), "Hz"), *((other_compasses(run, a, bins),) if several else ()))
            for a in run["attempts"]]
    return "<h2>Acquisition attempts</h2>" + table(
        ("attempt", "readings", "coverage", "target", "used / why not", "repeats dropped", "sensor rate",
         *(("other compasses: readings, coverage",) if several else ())), rows, numeric=(1, 2, 3, 5))


def _other_samples(run: dict[str, Any], accepted: dict[str, Any]) -> list[str]:
    """Each further compass's raw readings on its fitted ellipsoid and corrected on its sphere."""
    fitted = (run.get("calibration") or {}).get("magnetometers") or {}
    names = compass_names(run)
    out = []
    for device, raw in (accepted.get("others") or {}).items():
        name = names.get(device)
        cal = fitted.get(name) if name else None
        if cal and cal.get("soft_iron") and cal.get("hard_iron_ut"):
            out += [f"<h3>{html.escape(name)}</h3>", _samples_3d(cal, raw, f"samples3d-{name}")]
    return out


def _params(run: dict[str, Any]) -> str:
    stages = ("before", "written", "echoed", "read_back")
    names = sorted({n for stage in stages for n in run["params"].get(stage, {})})
    if not names:
        return "<h2>Parameters</h2><p class=note>nothing was written to the unit</p>"
    rows = [(n, *(param_text(run["params"].get(stage, {}).get(n)) for stage in stages)) for n in names]
    rule = f"<p class=note>{FLOAT32_RULE[:1].upper() + FLOAT32_RULE[1:]}.</p>"
    out = ["<h2>Parameters</h2>", rule,
           table(("parameter", "before", "written", "echoed", "read back after power cycle"), rows,
                 numeric=(1, 2, 3, 4))]
    persistence = persistence_rows(run.get("persistence"))
    if persistence:
        out += ["<h3>Power cycle</h3>", table(None, persistence)]
    return "".join(out)


def _phases(run: dict[str, Any]) -> str:
    rows = [(p["name"], p["outcome"], seconds(p["duration_s"] or 0.0), p["message"] or "") for p in run["phases"]]
    return "<h2>Phases</h2>" + table(("phase", "outcome", "duration", "message"), rows, numeric=(2,))


def write_unit_page(run: dict[str, Any], path: Path, plotly_src: str | None = None) -> Path:
    """``run``: a stored record as ``reading.find_run`` returns it, its attempts read with their
    raw arrays (``run_attempts(..., with_samples=True)``).  ``plotly_src``: as :func:`write_page`."""
    cal = run.get("calibration")
    accepted = next((a for a in run["attempts"] if a["accepted"] and a.get("raw") is not None), None)
    sections = [_identity(run), _measurements(run), _residual_charts(run)]
    if cal and accepted is not None:
        sections += ["<h2>Samples</h2>", _samples_3d(cal, accepted["raw"]), *_other_samples(run, accepted),
                     "<h2>Coverage</h2>", _coverage_3d(cal, accepted["raw"])]
        h = ", ".join(fmt(v) for v in cal["hard_iron_ut"])
        reference = fmt(run.get("reference_field_ut"), "µT")
        soft = "; ".join(", ".join(f"{v:.5f}" for v in row) for row in cal["soft_iron"])
        sections.append(f"<p>hard iron [{h}] µT; soft iron [{soft}]; "
                        f"field {fmt(cal['field_ut'], 'µT')} (reference {reference})</p>")
    else:
        sections.append("<h2>Samples</h2><p class=note>no accepted attempt: no calibration to draw</p>")
    sections += [_attempts(run), _params(run), _phases(run)]
    return write_page(path, f"magline — {run['serial']} run {run['id']}", sections, plotly_src)
