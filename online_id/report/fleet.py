"""The fleet page of ``online-id batch``: ``DIR/index.html``, every log's estimate side by side.

Drawn from the batch's rows and per-log JSON (:mod:`online_id.batch`): value ± σ per parameter per log
(flagged runs marked, a run that informed nothing marked, and why any row is not green), each log's handling
metrics with σ (:mod:`online_id.report.handling`), the logs placed by median speed and peak |a_y| with each
bin's estimates, and the failed logs with their error. Self-contained like the run report: it opens offline.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path

import numpy as np

from online_id.report.page import BAD, GOOD, NEUTRAL, PARAMETER_COLOURS, WARN, arr, document, esc, figure, fmt, table
from online_id.units import G
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS

#: Bins of median speed [km/h]: parking to motorway and a race track.
SPEED_BINS_KMH: tuple[float, ...] = (0.0, 30.0, 60.0, 90.0, 120.0, 160.0, math.inf)
#: Values of one parameter across the logs spanning more than this factor are drawn on a log axis.
WIDE_RANGE = 10.0
#: Bins of peak |a_y| [g]: within the linear tyre model (0.4 g, Haro's limit), beyond it, at a race car's grip.
AY_BINS_G: tuple[float, ...] = (0.0, 0.4, 0.8, 1.2, math.inf)


def _bin(value, edges) -> int | None:
    if value is None or not np.isfinite(value):
        return None
    return int(np.clip(np.searchsorted(edges, value, side="right") - 1, 0, len(edges) - 2))


def _edge_label(edges, k: int, unit: str) -> str:
    lo, hi = edges[k], edges[k + 1]
    return f"≥ {lo:g} {unit}" if not np.isfinite(hi) else f"{lo:g}-{hi:g} {unit}"


def entries(rows: list[dict]) -> list[dict]:
    """One entry per log from the batch's summary rows and their JSON: name, status, error, verdict (and
    ``nothing_learned``: the run informed none of its free parameters), the parameters ``informed`` and
    ``free`` (not fixed), ``handling`` (the estimate's JSON key, None from an older batch), ``values``/``std``
    (8,) [SI, NaN where absent], median speed [m/s] and peak |a_y| [m/s²] (None when the JSON has no ``run``:
    a log done by an older batch)."""
    out = []
    for row in rows:
        doc = {}
        if row.get("json"):
            try:
                doc = json.loads(Path(row["json"]).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                doc = {}
        run = doc.get("run") or {}

        def num(v):
            try:
                return float(v)
            except (TypeError, ValueError):
                return math.nan

        estimate = doc.get("estimate") or {}
        verdict = estimate.get("consistency") or {}
        informed = estimate.get("informed") or {}
        fixed = estimate.get("fixed") or {}
        out.append({"log": row.get("log", ""), "status": row.get("status", "failed"), "error": row.get("error", ""),
                    "samples": row.get("samples", ""), "consistent": row.get("consistent", ""),
                    "reasons": row.get("consistency_reasons", ""),
                    "nothing_learned": bool(verdict.get("nothing_learned")),
                    "informed": [n for n in PARAMETER_NAMES if informed.get(n)],
                    "free": [n for n in PARAMETER_NAMES if n in informed and n not in fixed],
                    "handling": estimate.get("handling"),
                    "values": np.array([num(row.get(n)) for n in PARAMETER_NAMES]),
                    "std": np.array([num(row.get(f"{n}_std")) for n in PARAMETER_NAMES]),
                    "median_speed": run.get("median_speed_mps"),
                    "peak_ay": run.get("max_abs_lateral_acceleration_mps2")})
    return out


def render(rows: list[dict], *, title: str = "online-id batch", generated: str | None = None) -> str:
    """The fleet page of a batch's summary ``rows`` (:data:`online_id.batch.SUMMARY_COLUMNS` and ``json``)."""
    logs = entries(rows)
    ok = [e for e in logs if e["status"] == "ok"]
    failed = [e for e in logs if e["status"] != "ok"]
    flagged = [e for e in ok if e["consistent"] == "no"]
    empty = [e for e in ok if e["nothing_learned"]]
    when = generated or _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    head = (f'<header class="top"><h1>{esc(title)}: {len(logs)} log(s)</h1><div class="sub">{len(ok)} ok'
            f' ({len(flagged)} flagged inconsistent, {len(empty)} that informed nothing), {len(failed)} failed'
            f' · made {esc(when)}</div>'
            '<nav class="toc"><a href="#estimates">Estimates</a><a href="#handling">Handling</a>'
            '<a href="#bins">By speed and |a_y|</a><a href="#failed">Failed</a></nav></header>')
    body = [head, "<main>", _estimates(ok), _handling(ok), _bins(ok), _failed(failed),
            '<footer>Made by online-id batch; figures drawn by plotly.js, inside this file (it opens offline).'
            " summary.csv beside this page holds the same numbers; each log's JSON holds the rest.</footer></main>"]
    return document(title, "".join(body))


def _name(e) -> str:
    return Path(e["log"]).name or e["log"]


def _state(e) -> str:
    """A log's verdict for the page: ``"flagged"`` (inconsistent), ``"empty"`` (the run informed nothing),
    ``"consistent"`` (judged, nothing failed, something learned) or ``"not judged"``."""
    if e["consistent"] == "no":
        return "flagged"
    if e["nothing_learned"]:
        return "empty"
    return "consistent" if e["consistent"] == "yes" else "not judged"


def _estimates(ok) -> str:
    if not ok:
        return '<section id="estimates"><h2>Estimates</h2><p class="muted">No log was estimated.</p></section>'
    head = (["log", "samples", "verdict", "informed"]
            + [f"{n} [{esc(PARAMETER_UNITS[n])}]" for n in PARAMETER_NAMES])
    rows, why = [], []
    for e in ok:
        state = _state(e)
        verdict = {"flagged": '<td class="flag" title="' + esc(e["reasons"]) + '">INCONSISTENT</td>',
                   "empty": f'<td class="warn" title="{esc(e["reasons"])}">NOTHING LEARNED</td>',
                   "consistent": '<td class="ok">consistent</td>'}.get(
            state, f'<td class="muted" title="{esc(e["reasons"])}">{esc(e["consistent"] or "—")}</td>')
        learned = e["informed"]
        missing = [n for n in e["free"] if n not in learned]
        count = f"{len(learned)}/{len(e['free'])}" if e["free"] else "—"
        cells = [f'<td class="text log" title="{esc(e["log"])}">{esc(_name(e))}</td>', f"<td>{esc(e['samples'])}</td>",
                 verdict, f'<td class="informed" title="not informed: {esc(", ".join(missing) or "none")}">'
                          f"{esc(count)}</td>"]
        cells += [f'<td class="value{"" if n in learned or n not in e["free"] else " uninformed"}" data-param="{n}"'
                  f' data-value="{float(e["values"][i])!r}">{fmt(e["values"][i])} ± {fmt(e["std"][i], 2)}</td>'
                  for i, n in enumerate(PARAMETER_NAMES)]
        rows.append(cells)
        if state != "consistent":
            why.append(f'<li><b>{esc(_name(e))}</b>: {esc(_why(e, state))}</li>')
    inner = [table(head, rows, cls="fleet", row_classes=[_ROW_CLASS.get(_state(e), "") for e in ok]),
             '<p class="caption">Value ± 1σ per parameter per log (SI units); grey values: not informed by that'
             " run (σ above half its prior σ: the prior's value, not the car's). Red: the run was judged"
             " inconsistent with the model: read its values as effective ones. Amber: the run informed none of the"
             " parameters. Only a green verdict is a result to compare.</p>"]
    if why:
        inner.append('<h3>Why a log is not green</h3><ul class="reasons why">' + "".join(why) + "</ul>")
    inner.append(_forest(ok))
    return '<section id="estimates"><h2>Estimates side by side</h2>' + "".join(inner) + "</section>"


#: A row's class by its state (page.css): red for flagged, amber for a run that informed nothing.
_ROW_CLASS = {"flagged": "flag", "empty": "warn"}


def _why(e, state: str) -> str:
    """One sentence: why the log's row is not green."""
    if state == "flagged":
        return f"inconsistent with the model: {e['reasons']}"
    if state == "empty":
        return e["reasons"] or "the run informed none of its parameters"
    return f"not judged: {e['reasons']}" if e["reasons"] else "not judged"


def _handling(ok) -> str:
    from online_id.report.handling import fleet_table

    logs = [{"name": _name(e), "log": e["log"], "handling": e["handling"], "flagged": e["consistent"] == "no",
             "nothing_learned": e["nothing_learned"]} for e in ok]
    if not any(e["handling"] for e in logs):
        return ('<section id="handling"><h2>Handling</h2><p class="muted">No log has handling metrics (logs done'
                " by an older batch: run it again with --force).</p></section>")
    return ('<section id="handling"><h2>Handling</h2>' + fleet_table(logs)
            + '<p class="caption">Each log\'s handling from its estimate, ± 1σ propagated from the estimate\'s'
              " covariance: understeer gradient [deg of road-wheel angle per g], characteristic speed (critical"
              " speed when the car oversteers: hover), the steady yaw-rate gain per steering-wheel angle and the yaw"
              " mode at the log's median speed. Red rows: judged inconsistent; grey rows: the run informed"
              " nothing (these numbers are the prior's).</p></section>")


def _forest(ok) -> str:
    """One panel per parameter: each log's value with its ±1σ bar, flagged logs in red."""
    names = [_name(e) for e in ok]
    cols = 4
    nrows = (len(PARAMETER_NAMES) + cols - 1) // cols
    data, layout = [], {"showlegend": False, "grid": {"rows": nrows, "columns": cols, "pattern": "independent"},
                        "hovermode": "closest"}
    for i, n in enumerate(PARAMETER_NAMES):
        ax = "" if i == 0 else str(i + 1)
        for flagged, colour in ((False, PARAMETER_COLOURS[i]), (True, BAD)):
            sel = [k for k, e in enumerate(ok) if (e["consistent"] == "no") == flagged]
            if not sel:
                continue
            data.append({"type": "scatter", "mode": "markers", "x": arr([ok[k]["values"][i] for k in sel]),
                         "y": [names[k] for k in sel], "xaxis": f"x{ax}", "yaxis": f"y{ax}",
                         "marker": {"color": colour, "size": 8, "symbol": "x" if flagged else "circle"},
                         "error_x": {"type": "data", "array": arr([ok[k]["std"][i] for k in sel]), "visible": True,
                                     "color": colour},
                         "hovertemplate": "%{y}: %{x:.5g}" + ("  (flagged)" if flagged else "") + "<extra></extra>"})
        values = np.array([e["values"][i] for e in ok])
        values = values[np.isfinite(values) & (values > 0)]
        wide = len(values) > 1 and values.max() / values.min() > WIDE_RANGE  # a flagged log far off: log scale
        layout[f"xaxis{ax}"] = {"title": {"text": f"{n} [{PARAMETER_UNITS[n]}]" + (" (log)" if wide else ""),
                                          "font": {"size": 11}}, "type": "log" if wide else "linear"}
        layout[f"yaxis{ax}"] = {"showticklabels": i % cols == 0, "type": "category", "categoryarray": names,
                                "automargin": True}
    return figure("fleet-forest", data, layout, height=max(320, nrows * (60 + 22 * len(ok))),
                  caption="Each parameter across the logs, value ± 1σ; red crosses: runs flagged inconsistent.")


def _bins(ok) -> str:
    placed = [e for e in ok if e["median_speed"] is not None and e["peak_ay"] is not None]
    if not placed:
        return ('<section id="bins"><h2>By speed and |a_y|</h2><p class="muted">No log has its speed and |a_y|'
                " recorded (logs done by an older batch: run it again with --force).</p></section>")
    speed_kmh = [3.6 * e["median_speed"] for e in placed]
    ay_g = [e["peak_ay"] / G for e in placed]
    data = []
    groups = (("consistent", GOOD, "consistent", "circle"), ("flagged", BAD, "flagged inconsistent", "x"),
              ("empty", WARN, "informed nothing", "diamond-open"),
              ("not judged", NEUTRAL, "not judged (too short to test)", "circle-open"))
    for state, colour, label, symbol in groups:
        sel = [k for k, e in enumerate(placed) if _state(e) == state]
        if sel:
            data.append({"type": "scatter", "mode": "markers+text", "x": arr([speed_kmh[k] for k in sel]),
                         "y": arr([ay_g[k] for k in sel]), "text": [_name(placed[k]) for k in sel],
                         "textposition": "top center", "name": label,
                         "marker": {"color": colour, "size": 10, "symbol": symbol}})
    shapes = ([{"type": "line", "xref": "x", "yref": "paper", "x0": e, "x1": e, "y0": 0, "y1": 1,
                "line": {"color": "#ccc", "dash": "dot"}} for e in SPEED_BINS_KMH[1:-1]]
              + [{"type": "line", "yref": "y", "xref": "paper", "y0": e, "y1": e, "x0": 0, "x1": 1,
                  "line": {"color": "#ccc", "dash": "dot"}} for e in AY_BINS_G[1:-1]])
    fig = figure("fleet-bins", data, {"shapes": shapes, "xaxis": {"title": {"text": "median speed [km/h]"}},
                                      "yaxis": {"title": {"text": "peak |a_y| [g]"}, "rangemode": "tozero"},
                                      "legend": {"orientation": "h", "y": 1.1}}, height=380,
                 caption="Each log by its median speed and peak |a_y|; dotted lines are the bins of the table below.")
    cells: dict[tuple[int, int], list] = {}
    for e, v, a in zip(placed, speed_kmh, ay_g):
        cells.setdefault((_bin(v, SPEED_BINS_KMH), _bin(a, AY_BINS_G)), []).append(e)
    head = ["median speed", "peak |a_y|", "logs", "flagged"] + [f"{n} median (spread)" for n in PARAMETER_NAMES]
    rows = []
    for (sb, ab), es in sorted(cells.items()):
        vals = np.array([e["values"] for e in es])
        row = [f'<td>{_edge_label(SPEED_BINS_KMH, sb, "km/h")}</td>', f'<td>{_edge_label(AY_BINS_G, ab, "g")}</td>',
               f'<td class="text">{esc(", ".join(_name(e) for e in es))}</td>',
               f"<td>{sum(e['consistent'] == 'no' for e in es)}</td>"]
        for i in range(len(PARAMETER_NAMES)):
            col = vals[:, i][np.isfinite(vals[:, i])]
            spread = f" ({fmt(np.ptp(col), 2)})" if len(col) > 1 else ""
            row.append(f"<td>{fmt(np.median(col)) if len(col) else '—'}{spread}</td>")
        rows.append(row)
    return ('<section id="bins"><h2>By speed and |a_y|</h2>' + fig + table(head, rows, cls="bins")
            + '<p class="caption">The logs of each bin and, per parameter, the median of their values and the range'
              " between the lowest and highest (flagged runs included: see the count).</p></section>")


def _failed(failed) -> str:
    if not failed:
        return '<section id="failed"><h2>Failed logs</h2><p class="muted">None.</p></section>'
    rows = [[f'<td class="text log">{esc(e["log"])}</td>', f'<td class="text error">{esc(e["error"])}</td>']
            for e in failed]
    return ('<section id="failed"><h2>Failed logs</h2>' + table(["log", "error"], rows, cls="failed")
            + "</section>")
