"""The handling metrics on a page: a table of value ± σ, the yaw-rate/steering Bode plot (the model's curve with
its ±σ band, the run's measured response over it) and the steady yaw-rate gain over speed.

Drawn from the ``handling`` key of an estimate's or a fit's JSON (:meth:`online_id.handling.Handling.to_json_dict`),
so the run page (from result objects) and the fleet page (from each log's JSON) draw the same thing from the same
numbers. Every value in a table carries ``data-metric`` and ``data-value`` (the browser tests read them).
"""

from __future__ import annotations

import math

import numpy as np

from online_id.report.page import BAD, NEUTRAL, arr, esc, figure, fmt, table

#: The metrics shown, in order: (key in the JSON, label, unit shown, factor from the JSON's unit).
METRICS: tuple[tuple[str, str, str, float], ...] = (
    ("understeer_gradient", "understeer gradient", "deg/g", 1.0),
    ("characteristic_speed", "characteristic speed", "km/h", 3.6),
    ("yaw_rate_gain", "steady yaw-rate gain", "1/s", 1.0),
    ("yaw_natural_frequency", "yaw natural frequency", "Hz", 1.0),
    ("yaw_damping", "yaw damping ratio", "", 1.0),
)
#: The lower edge of a ±σ band on a log axis, as a fraction of the curve (a σ wider than the value).
POSITIVE_FLOOR = 0.01
#: The colours of the estimate's and the fit's curves.
ESTIMATE_COLOUR, FIT_COLOUR = "#1f77b4", "#ff7f0e"


def value_text(entry: dict | None, factor: float = 1.0) -> str:
    """``value ± σ`` of a metric's JSON entry (σ "?" when not determined), "—" without a value."""
    if not entry or entry.get("value") is None:
        return "—"
    v = entry["value"] * factor
    s = entry.get("std")
    return f"{fmt(v, 4)} ± {fmt(s * factor, 2)}" if s is not None else f"{fmt(v, 4)} ± ?"


def label(key: str, entry: dict | None) -> str:
    """The metric's name; the characteristic speed says when it is the critical one (oversteer)."""
    name = dict((k, lab) for k, lab, _, _ in METRICS)[key]
    if key == "characteristic_speed" and entry and entry.get("kind") == "critical":
        return "critical speed"
    return name


def cell(key: str, entry: dict | None, factor: float, cls: str = "metric") -> str:
    """A table cell with the metric's full value (in the unit shown) in ``data-value``; a critical speed says so
    on hover."""
    value = None if not entry or entry.get("value") is None else entry["value"] * factor
    data = f' data-value="{float(value)!r}"' if value is not None else ""
    title = (' title="critical speed: the car oversteers"' if key == "characteristic_speed" and entry
             and entry.get("kind") == "critical" else "")
    return f'<td class="{cls}" data-metric="{esc(key)}"{data}{title}>{esc(value_text(entry, factor))}</td>'


def section(estimate: dict | None, fit: dict | None = None) -> str:
    """The run page's handling: the table (estimate, and the fit when made), the Bode plot, the gain over speed."""
    if not estimate:
        return '<p class="muted">No handling metrics (they were not computed for this estimate).</p>'
    speed = estimate.get("speed_mps") or math.nan
    head = ["metric", f"estimate (at {3.6 * speed:.0f} km/h)", "unit"] + (["fit", ""] if fit else [])
    rows = []
    for key, _, unit, factor in METRICS:
        row = [f'<td>{esc(label(key, estimate.get(key)))}</td>', cell(key, estimate.get(key), factor),
               f'<td class="text">{esc(unit)}</td>']
        if fit:
            row.append(cell(key, fit.get(key), factor, cls="fit-metric"))
            row.append(_agreement(estimate.get(key), fit.get(key)))
        rows.append(row)
    notes = list(estimate.get("notes") or [])
    measured = estimate.get("measured_response")
    parts = [table(head, rows, cls="handling"),
             '<p class="caption">From the linear model at the estimated parameters, ±1σ propagated from their'
             " covariance (after every widening): understeer gradient in degrees of road-wheel angle per g;"
             " characteristic speed √(L/K) where the steady yaw-rate gain peaks (critical speed √(−L/K) for an"
             " oversteering car); yaw-rate gain per steering-wheel angle; the yaw mode at the run's median speed."
             + (" The fit's column: the same from the batch fit (z: their difference in combined σ)." if fit else "")
             + "".join(f" {esc(n)}." for n in notes) + "</p>",
             bode_figure(estimate, fit), gain_figure(estimate, fit)]
    if measured is not None and not measured.get("frequency_hz"):
        parts.append('<p class="muted">The run\'s own response could not be measured: at no frequency did the'
                     f" steering explain the yaw rate (coherence ≥ {measured.get('min_coherence', 0.5):g}).</p>")
    return "".join(parts)


def _agreement(a: dict | None, b: dict | None) -> str:
    if not a or not b or a.get("value") is None or b.get("value") is None:
        return "<td>—</td>"
    sa, sb = a.get("std"), b.get("std")
    if sa is None or sb is None or not math.hypot(sa, sb) > 0:
        return "<td>—</td>"
    z = (a["value"] - b["value"]) / math.hypot(sa, sb)
    return f'<td class="{"flag" if abs(z) > 3 else "ok"}">z {z:+.2f}</td>'


def _band(x, y, s, colour: str, axis: str, name: str, group: str, positive: bool = False) -> list[dict]:
    """The ±σ band (two lines, the second filled to the first) and the curve; ``positive``: a log axis, whose
    band stops at :data:`POSITIVE_FLOOR` of the curve (it cannot reach zero)."""
    y, s = np.asarray(y, dtype=float), np.asarray(s, dtype=float)
    common = {"xaxis": "x", "yaxis": axis, "hoverinfo": "skip", "legendgroup": group, "showlegend": False}
    low = np.maximum(y - s, POSITIVE_FLOOR * y) if positive else y - s
    out = []
    if np.isfinite(s).any():
        out += [{"type": "scatter", "mode": "lines", "x": arr(x), "y": arr(y + s), "line": {"width": 0}, **common},
                {"type": "scatter", "mode": "lines", "x": arr(x), "y": arr(low), "line": {"width": 0},
                 "fill": "tonexty", "fillcolor": _rgba(colour, 0.22), **common}]
    out.append({"type": "scatter", "mode": "lines", "x": arr(x), "y": arr(y), "name": name, "legendgroup": group,
                "showlegend": axis == "y", "xaxis": "x", "yaxis": axis, "line": {"width": 1.8, "color": colour}})
    return out


def bode_figure(estimate: dict, fit: dict | None = None, element_id: str = "handling-bode") -> str:
    """Magnitude (log-log) and phase of yaw rate over steering-wheel angle: the estimate's model ±σ, the fit's
    model (dashed, when given) and the run's measured response (markers)."""
    data = []
    for h, colour, name in ((estimate, ESTIMATE_COLOUR, "model at the estimate ± 1σ"),
                            (fit, FIT_COLOUR, "model at the fit ± 1σ")):
        fr = (h or {}).get("frequency_response")
        if not fr:
            continue
        data += _band(fr["frequency_hz"], fr["magnitude"], _nan(fr["magnitude_std"]), colour, "y", name, name,
                      positive=True)
        data += _band(fr["frequency_hz"], fr["phase_deg"], _nan(fr["phase_deg_std"]), colour, "y2", name, name)
    m = estimate.get("measured_response")
    if m and m.get("frequency_hz"):
        sp = m.get("speed_mps") or {}
        name = (f"measured in the run (coherence ≥ {m.get('min_coherence', 0.5):g};"
                f" {3.6 * sp.get('min', 0):.0f}-{3.6 * sp.get('max', 0):.0f} km/h)")
        hover = "%{x:.3g} Hz: %{y:.4g}  (coherence %{customdata:.2f})<extra></extra>"
        for axis, key in (("y", "magnitude"), ("y2", "phase_deg")):
            data.append({"type": "scatter", "mode": "markers", "x": arr(m["frequency_hz"]), "y": arr(m[key]),
                         "customdata": arr(m["coherence"], 3), "name": name, "legendgroup": "measured",
                         "showlegend": axis == "y", "xaxis": "x", "yaxis": axis, "hovertemplate": hover,
                         "marker": {"size": 5, "color": BAD, "symbol": "circle-open"}})
    layout = {"hovermode": "closest", "legend": {"orientation": "h", "y": 1.12},
              "xaxis": {"type": "log", "title": {"text": "frequency [Hz]"}, "anchor": "y2"},
              "yaxis": {"type": "log", "domain": [0.52, 1.0], "anchor": "x",
                        "title": {"text": "|r/δH| [1/s]"}},
              "yaxis2": {"domain": [0.0, 0.44], "anchor": "x", "title": {"text": "phase [deg]"}}}
    speed = estimate.get("speed_mps") or math.nan
    return figure(element_id, data, layout, height=460,
                  caption=f"Yaw rate over steering-wheel angle at {3.6 * speed:.0f} km/h (the run's median speed):"
                          " the model at the estimate with its ±1σ band, and the response measured in the run"
                          " (Welch's cross-spectrum, only where the steering explains the yaw rate). A real log's"
                          " speed varies: its measured response is the run's average.")


def gain_figure(estimate: dict, fit: dict | None = None, element_id: str = "handling-gain") -> str:
    """The steady yaw-rate gain over speed ±σ, the run's median speed and the characteristic speed marked."""
    data = []
    for h, colour, name in ((estimate, ESTIMATE_COLOUR, "estimate ± 1σ"), (fit, FIT_COLOUR, "fit ± 1σ")):
        g = (h or {}).get("yaw_rate_gain_by_speed")
        if not g:
            continue
        data += _band(3.6 * np.asarray(g["speed_mps"]), g["value"], _nan(g["std"]), colour, "y", name, name)
    shapes, notes = [], []
    speed = estimate.get("speed_mps")
    ch = estimate.get("characteristic_speed") or {}
    for v, text in ((speed, "run's median speed"), (ch.get("value"), label("characteristic_speed", ch))):
        if v is not None and 0 < 3.6 * v < 3.6 * max((estimate.get("yaw_rate_gain_by_speed") or {}).get(
                "speed_mps", [0]), default=0):
            shapes.append({"type": "line", "xref": "x", "yref": "paper", "x0": 3.6 * v, "x1": 3.6 * v, "y0": 0,
                           "y1": 1, "line": {"color": NEUTRAL, "dash": "dot"}})
            notes.append({"x": 3.6 * v, "y": 1, "xref": "x", "yref": "paper", "text": text, "showarrow": False,
                          "yanchor": "bottom", "font": {"size": 11}})
    layout = {"hovermode": "x unified", "legend": {"orientation": "h", "y": 1.15}, "shapes": shapes,
              "annotations": notes, "xaxis": {"title": {"text": "speed [km/h]"}},
              "yaxis": {"title": {"text": "steady r/δH [1/s]"}, "rangemode": "tozero"}}
    return figure(element_id, data, layout, height=320,
                  caption="The steady-state yaw-rate gain per steering-wheel angle over speed, ±1σ: it peaks at the"
                          " characteristic speed of an understeering car.")


def fleet_table(logs: list[dict]) -> str:
    """One row per log (``{"name", "handling", "flagged"}``) with each metric ± σ."""
    head = ["log", "at"] + [f"{lab} [{unit}]" if unit else lab for _, lab, unit, _ in METRICS]
    rows, classes = [], []
    for e in logs:
        h = e.get("handling") or {}
        speed = h.get("speed_mps")
        row = [f'<td class="text log" title="{esc(e.get("log", ""))}">{esc(e["name"])}</td>',
               f"<td>{'—' if speed is None else f'{3.6 * speed:.0f} km/h'}</td>"]
        row += [cell(key, h.get(key), factor) for key, _, _, factor in METRICS]
        rows.append(row)
        classes.append("flag" if e.get("flagged") else "dim" if e.get("nothing_learned") else "")
    return table(head, rows, cls="handling-fleet", row_classes=classes)


def _nan(values) -> list[float]:
    return [math.nan if v is None else v for v in values]


def _rgba(hex_colour: str, alpha: float) -> str:
    h = hex_colour.lstrip("#")
    return f"rgba({int(h[0:2], 16)},{int(h[2:4], 16)},{int(h[4:6], 16)},{alpha})"
