"""The page of one run (``online-id report``): drawn from a :class:`~online_id.workflows.results.Report`.

Sections: the run (its channels, speed and |a_y|, what ``check`` says), the estimate (table, verdict,
trajectories with ±σ bands, innovations against their spread), the handling metrics (value ± σ, the
yaw-rate/steering Bode plot with the run's measured response, :mod:`online_id.report.handling`), the
excitation meter, the fit and its
agreement with the estimate, the diagnosis, and the commands that reproduce each part. Every number in
a table carries ``data-*`` attributes with its full value (the browser tests read them).
"""

from __future__ import annotations

import datetime as _dt

import numpy as np

from online_id.report.page import (
    BAD,
    GOOD,
    MAX_POINTS,
    NEUTRAL,
    PARAMETER_COLOURS,
    arr,
    document,
    envelope,
    esc,
    figure,
    fmt,
    stride,
    table,
    verdict_block,
)
from online_id.units import CHANNEL_UNITS, G
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS

#: How each channel is drawn: (label, unit shown, factor from SI).
CHANNEL_DISPLAY = {
    "steering_wheel_angle": ("steering wheel", "deg", float(np.degrees(1.0))),
    "yaw_rate": ("yaw rate", "deg/s", float(np.degrees(1.0))),
    "lateral_acceleration": ("lateral acceleration", "m/s²", 1.0),
    "roll_angle": ("roll angle", "deg", float(np.degrees(1.0))),
    "roll_rate": ("roll rate", "deg/s", float(np.degrees(1.0))),
}
#: A log clock that starts later than this [s] is named on the time axes, which count from the start.
TIME_ORIGIN_SHOWN_S = 0.5
#: The start of a run left out of the trajectories' y range [fraction of the run]: the prior's wide band.
RANGE_SKIP_FRACTION = 0.1
#: Top of the bound figure [% relative σ]: a bound above it is "not determined" many times over.
BOUND_TOP_PERCENT = 300.0
#: The meter's colours are logarithmic in the share, from this [%] (white: nothing to speak of) to 100 %:
#: a window holding 80 % of a parameter's information (a glitch) and one of 200 windows holding its even
#: 0.5 % both read, where a linear scale shows only the first.
METER_FLOOR_PERCENT = 0.05
#: Heat-map colours of the excitation meter: white (under the floor) to dark blue (all of the run's).
METER_COLOURS = [[0.0, "#ffffff"], [0.15, "#deebf7"], [0.5, "#6baed6"], [0.8, "#2171b5"], [1.0, "#08306b"]]


def render(rep, *, generated: str | None = None) -> str:
    """The page of ``rep`` (a :class:`~online_id.workflows.results.Report`), as one HTML document."""
    est = rep.estimate.result
    when = generated or _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    duration = est.sim_seconds
    parts = [("run", "The run"), ("estimate", "The estimate"), ("handling", "Handling"),
             ("excitation", "Excitation meter"), ("fit", "The fit"), ("diagnosis", "The diagnosis"),
             ("commands", "Reproduce")]
    toc = "".join(f'<a href="#{k}">{esc(v)}</a>' for k, v in parts)
    head = (f'<header class="top"><h1>online-id report: {esc(rep.source)}</h1>'
            f'<div class="sub">vehicle {esc(rep.vehicle)} · {est.filter.upper()} · {est.samples:,} samples,'
            f' {duration:.1f} s · made {esc(when)}'
            + (f' · <b>interrupted during {esc(rep.interrupted)}</b>' if rep.interrupted else "")
            + f'</div><nav class="toc">{toc}</nav></header>')
    body = [head, "<main>", _summary(rep), _run(rep), _estimate(rep), _handling(rep), _excitation(rep), _fit(rep),
            _diagnosis(rep), _commands(rep),
            '<footer>Made by online-id; figures drawn by plotly.js, inside this file (it opens offline).'
            " Drag to zoom, double-click to reset, hover for values.</footer>", "</main>"]
    return document(f"online-id report: {rep.source}", "".join(body))


# -- the top --------------------------------------------------------------------------------------------

def _summary(rep) -> str:
    est = rep.estimate.result
    out = [verdict_block(est.consistency, "estimate")]
    cards = []
    if rep.check is not None:
        c = rep.check.result
        cards += [("median speed", f"{3.6 * c.speed['median']:.0f} km/h"),
                  ("peak |a_y|", f"{c.lateral_acceleration['max_abs'] / G:.2f} g"),
                  ("not determined by the run", ", ".join(c.not_determined) or "none")]
    missing = [n for n, ok in est.informed.items() if not ok and n not in est.fixed]
    cards.append(("not informed by the run", ", ".join(missing) or "none"))  # the estimate's final σ
    if rep.agreement is not None:
        dis = [n for n, a in rep.agreement.items() if a["disagree"]]
        cards.append(("fit disagrees (|z| > 3)", ", ".join(dis) or "none"))
    if rep.diagnosis is not None:
        cards.append(("diagnosis", rep.diagnosis.result.verdict or "no effect explains the gap"))
    out.append('<div class="cards">' + "".join(
        f'<div class="card"><div class="k">{esc(k)}</div><div class="v">{esc(v)}</div></div>' for k, v in cards)
        + "</div>")
    return "".join(out)


def _section(key: str, title: str, inner: str) -> str:
    return f'<section id="{key}"><h2>{esc(title)}</h2>{inner}</section>'


def _not_made(rep, part: str) -> str | None:
    if part in rep.errors:
        return f'<p class="error">{esc(part)} failed: {esc(rep.errors[part])}</p>'
    if part in rep.skipped:
        return f'<p class="muted">Not made (--no-{esc(part)}): run <code>{esc(rep.commands.get(part, ""))}</code>.</p>'
    if rep.interrupted:
        return f'<p class="muted">Not made: the report was interrupted during {esc(rep.interrupted)}.</p>'
    return None


# -- the run --------------------------------------------------------------------------------------------

def _run(rep) -> str:
    run = rep.run
    inner = [_channels_figure(run), _speed_ay_figure(rep)]
    miss = _not_made(rep, "check")
    if miss:
        return _section("run", "The run", "".join(inner) + miss)
    c = rep.check.result
    s, st, ay = c.speed, c.steering, c.lateral_acceleration
    facts = [
        f"{c.samples:,} samples, {c.duration_s:.1f} s at {c.rate_hz:.4g} Hz (jitter"
        f" {f'{c.jitter_s * 1e3:.2g} ms' if c.jitter_s >= 1e-6 else 'none'}, {len(c.gaps)} gap(s))",
        f"channels: {', '.join(c.channels_present)}" + (f"; missing: {', '.join(c.channels_missing)}"
                                                        if c.channels_missing else ""),
        f"speed {s['min']:.1f}-{s['max']:.1f} m/s (median {s['median']:.1f});"
        f" {100 * s['below_min_speed_fraction']:.1f} % under {s['min_speed']:g} m/s",
        f"steering wheel RMS {np.degrees(st['rms_rad']):.2f} deg, max {np.degrees(st['max_abs_rad']):.1f} deg;"
        f" 95 % of its variance under {st['f95_hz']:.2f} Hz; {100 * st['above_1hz_fraction']:.1f} % above 1 Hz",
        f"|a_y| max {ay['max_abs']:.2f} m/s² ({ay['max_abs'] / G:.2f} g); {100 * ay['above_linear_fraction']:.1f} %"
        " of samples above 0.4 g (the linear tyre model's range)",
    ]
    inner.append("<h3>What the run can tell (check)</h3><ul>" + "".join(f"<li>{esc(f)}</li>" for f in facts)
                 + "</ul>")
    head = ["param", "Cramér-Rao σ %", "at the log's noise"] + [f"{esc(k.label)} %" for k in c.candidates] + [""]
    rows = []
    floor = c.crlb_at_noise_floor
    for i, n in enumerate(PARAMETER_NAMES):
        und = n in c.not_determined
        row = [f'<td>{n}</td>', _pct(c.crlb.crlb_relative_std[i]),
               _pct(floor.crlb_relative_std[i]) if floor is not None else "—"]
        row += [_pct(k.crlb_relative_std[i]) for k in c.candidates]
        row.append('<td class="flag">NOT DETERMINED</td>' if und else '<td class="ok">determined</td>')
        rows.append(row)
    inner.append(table(head, rows))
    inner.append('<p class="caption">The bound on each parameter\'s relative σ from this run\'s inputs at the'
                 f' prior ({esc(c.linearised_at)}); candidates add a channel or a manoeuvre: '
                 + "; ".join(f"{esc(k.label)}: {esc(k.description)}" for k in c.candidates) + ".</p>")
    if c.advice:
        inner.append("<h3>Advice</h3><ul>" + "".join(f"<li>{esc(a)}</li>" for a in c.advice) + "</ul>")
    return _section("run", "The run", "".join(inner))


def _pct(v) -> str:
    return f"<td>{fmt(100 * v, 3)}</td>" if np.isfinite(v) else "<td>∞</td>"


def _origin(run) -> float:
    """The run's first time [s]: every time axis counts from it (a CAN log's bus clock reads 46,410 s)."""
    return float(run.time[0]) if run is not None and len(run.time) else 0.0


def _time_title(t0: float) -> str:
    """A time axis's title, naming the log's own clock at the start when it is not zero."""
    return "time [s]" if abs(t0) < TIME_ORIGIN_SHOWN_S else f"time from the start [s] (log clock {t0:,.2f} s at 0)"


def _stacked_axes(n: int, gap: float = 0.04) -> list[list[float]]:
    """Vertical domains of ``n`` stacked panels, top first."""
    h = (1 - gap * (n - 1)) / n
    return [[1 - (k + 1) * h - k * gap, 1 - k * h - k * gap] for k in range(n)]


def _channels_figure(run) -> str:
    chans = [c for c in CHANNEL_DISPLAY if getattr(run, c, None) is not None]
    domains = _stacked_axes(len(chans))
    t0 = _origin(run)
    data, layout = [], {"showlegend": False, "hovermode": "x unified",
                        "xaxis": {"title": {"text": _time_title(t0)}, "anchor": f"y{len(chans)}"}}
    for k, c in enumerate(chans):
        label, unit, factor = CHANNEL_DISPLAY[c]
        t, y = envelope(run.time - t0, getattr(run, c) * factor)
        ax = "" if k == 0 else str(k + 1)
        data.append({"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(y), "name": label,
                     "xaxis": "x", "yaxis": f"y{ax}", "line": {"width": 1, "color": "#34495e"}})
        layout[f"yaxis{ax}"] = {"domain": domains[k], "title": {"text": f"{label}<br>[{unit}]",
                                                                "font": {"size": 11}}, "anchor": "x"}
    return figure("run-channels", data, layout, height=120 * len(chans) + 60,
                  caption="The logged channels over the run (each line keeps every peak: the lowest and highest"
                          " value of each of ~750 slices).")


def _speed_ay_figure(rep) -> str:
    from online_id.filters.config import FilterConfig

    run = rep.run
    limit = FilterConfig().linear_range_ay
    t0 = _origin(run)
    t, v = envelope(run.time - t0, run.speed * 3.6)
    data = [{"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(v), "name": "speed",
             "yaxis": "y", "line": {"width": 1.2, "color": "#34495e"}}]
    layout = {"hovermode": "x unified", "legend": {"orientation": "h", "y": 1.12},
              "xaxis": {"title": {"text": _time_title(t0)}, "anchor": "y2"},
              "yaxis": {"domain": [0.56, 1], "title": {"text": "speed [km/h]"}, "anchor": "x"},
              "yaxis2": {"domain": [0, 0.44], "title": {"text": "|a_y| [g]"}, "anchor": "x", "rangemode": "tozero"}}
    if run.lateral_acceleration is not None:
        t, a = envelope(run.time - t0, np.abs(run.lateral_acceleration) / G)
        data.append({"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(a), "name": "|a_y|", "yaxis": "y2",
                     "line": {"width": 1, "color": "#8e44ad"}})
        start, t1 = 0.0, float(run.time[-1] - t0)
        for level, name, colour in ((0.4, "0.4 g: the linear tyre model's range (check)", NEUTRAL),
                                    (limit / G, f"{limit / G:.2g} g: the filter learns only below", BAD)):
            data.append({"type": "scatter", "mode": "lines", "x": [start, t1], "y": [level, level], "name": name,
                         "yaxis": "y2", "line": {"width": 1.2, "dash": "dash", "color": colour}, "hoverinfo": "skip"})
    return figure("run-speed-ay", data, layout, height=380,
                  caption="Speed and |a_y|: the filter propagates through every sample but learns only where |a_y|"
                          " is under its linear range.")


# -- the estimate -----------------------------------------------------------------------------------------

def _estimate(rep) -> str:
    est = rep.estimate.result
    truth = None if est.truth is None else est.truth.to_vector()
    head = ["param", "unit", "prior", "estimate", "1σ", "1σ %", "informed", "moved [prior σ]"]
    if truth is not None:
        head += ["truth", "error %"]
    rows = []
    values, prior = est.parameters.to_vector(), est.prior.to_vector()
    for i, n in enumerate(PARAMETER_NAMES):
        fixed = n in est.fixed
        informed = "FIXED" if fixed else "yes" if est.informed[n] else "no"
        row = [f'<td>{n}</td>', f'<td class="text">{esc(PARAMETER_UNITS[n])}</td>', f"<td>{fmt(prior[i])}</td>",
               f'<td class="value" data-param="{n}" data-value="{float(values[i])!r}">{fmt(values[i])}</td>',
               f'<td class="std" data-param="{n}" data-value="{float(est.std[i])!r}">{fmt(est.std[i], 3)}</td>',
               f"<td>{fmt(100 * est.relative_std[i], 3)}</td>", f"<td>{informed}</td>",
               f"<td>{est.moved_prior_sigma[i]:.1f}</td>"]
        if truth is not None:
            row += [f"<td>{fmt(truth[i])}</td>", f"<td>{100 * (values[i] / truth[i] - 1):.3f}</td>"]
        rows.append(row)
    dim = ["dim" if n not in est.fixed and not est.informed[n] else "" for n in PARAMETER_NAMES]
    inner = [table(head, rows, cls="estimate", row_classes=dim),
             '<p class="caption">Grey rows: not informed by this run (σ above half its prior σ): the value is the'
             " prior's, not the data's. " + esc(est.events_summary()) + "</p>",
             verdict_block(est.consistency, "verdict")]
    if est.polish:
        p = est.polish
        what = p.get("error") or p.get("status") or "the batch polish replaced the filter's estimate"
        took = f' ({p["iterations"]} evaluations, {p["wall_s"]:.1f} s)' if "iterations" in p else ""
        inner.append(f'<p class="muted">polish: {esc(what)}{esc(took)}</p>')
    inner.append(_trajectories_figure(est, _origin(rep.run)))
    inner.append(_innovations_figure(rep))
    return _section("estimate", "The estimate", "".join(inner))


def _trajectories_figure(est, t0: float = 0.0) -> str:
    tr = est.trace
    idx = stride(len(tr.time))
    t = tr.time[idx] - t0
    cols = 2
    rows = (len(PARAMETER_NAMES) + cols - 1) // cols
    data, layout = [], {"showlegend": False, "hovermode": "x unified", "grid": {"rows": rows, "columns": cols,
                                                                                "pattern": "independent"}}
    truth = None if est.truth is None else est.truth.to_vector()
    prior = est.prior.to_vector()
    skip = t >= t[0] + RANGE_SKIP_FRACTION * (t[-1] - t[0]) if len(t) > 1 else np.ones(len(t), bool)
    for i, n in enumerate(PARAMETER_NAMES):
        ax = "" if i == 0 else str(i + 1)
        v, s = tr.values[idx, i], tr.std[idx, i]
        colour = PARAMETER_COLOURS[i]
        common = {"xaxis": f"x{ax}", "yaxis": f"y{ax}", "hoverinfo": "skip"}
        data += [{"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(v + s), "line": {"width": 0},
                  **common},
                 {"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(v - s), "line": {"width": 0},
                  "fill": "tonexty", "fillcolor": _rgba(colour, 0.22), **common},
                 {"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(v), "name": n,
                  "line": {"width": 1.6, "color": colour}, "xaxis": f"x{ax}", "yaxis": f"y{ax}",
                  "hovertemplate": f"{n} %{{y:.5g}}<extra></extra>"},
                 {"type": "scatter", "mode": "lines", "x": [t[0], t[-1]], "y": [prior[i], prior[i]],
                  "line": {"width": 1, "dash": "dot", "color": NEUTRAL}, **common}]
        lo, hi = np.nanmin((v - s)[skip]), np.nanmax((v + s)[skip])
        marks = [prior[i]]
        if truth is not None:
            data.append({"type": "scatter", "mode": "lines", "x": [t[0], t[-1]], "y": [truth[i], truth[i]],
                         "line": {"width": 1.2, "dash": "dash", "color": GOOD}, **common})
            marks.append(truth[i])
        lo, hi = min(lo, *marks), max(hi, *marks)
        pad = 0.08 * (hi - lo) if hi > lo else 0.05 * abs(hi) + 1e-12
        layout[f"yaxis{ax}"] = {"range": [float(lo - pad), float(hi + pad)], "title": {
            "text": f"{n} [{PARAMETER_UNITS[n]}]", "font": {"size": 11}}}
        layout[f"xaxis{ax}"] = {"title": {"text": _time_title(t0)}} if i >= len(PARAMETER_NAMES) - cols else {}
    return figure("estimate-trajectories", data, layout, height=190 * rows + 40,
                  caption="Each parameter's estimate over the run with its ±1σ band (the filter's own, before the"
                          " polish), the prior (grey dotted)" + (" and the truth (green dashed)" if truth is not None
                                                                 else "") + ". The first 10 % of the run is left out"
                          " of each panel's range: the prior's band is wide there (double-click to see it all).")


def _rgba(hex_colour: str, alpha: float) -> str:
    h = hex_colour.lstrip("#")
    return f"rgba({int(h[0:2], 16)},{int(h[2:4], 16)},{int(h[4:6], 16)},{alpha})"


def _innovations_figure(rep) -> str:
    wins = rep.innovations
    if not wins:
        return '<p class="muted">No innovations recorded (no correction was made).</p>'
    domains = _stacked_axes(len(wins), gap=0.1)
    t0 = _origin(rep.run)
    data, layout = [], {"hovermode": "x unified", "legend": {"orientation": "h", "y": 1.12},
                        "xaxis": {"title": {"text": _time_title(t0)}, "anchor": f"y{len(wins)}"}}
    details = (rep.estimate.result.consistency or {}).get("innovations", {}).get("channels", {})
    notes = []
    for k, w in enumerate(wins):
        ax = "" if k == 0 else str(k + 1)
        label = CHANNEL_DISPLAY.get(w.channel, (w.channel,))[0]
        first = k == 0
        data += [{"type": "scatter", "mode": "lines", "x": arr(w.middle - t0), "y": arr(w.rms),
                  "name": "RMS per window",
                  "legendgroup": "rms", "showlegend": first, "yaxis": f"y{ax}", "line": {"color": "#34495e",
                                                                                            "width": 1.4}},
                 {"type": "scatter", "mode": "lines", "x": arr(w.middle - t0), "y": arr(w.bound),
                  "name": "the verdict's limit for a window", "legendgroup": "bound", "showlegend": first,
                  "yaxis": f"y{ax}", "line": {"color": BAD, "width": 1, "dash": "dash"}},
                 {"type": "scatter", "mode": "lines", "x": [float(w.middle[0] - t0), float(w.middle[-1] - t0)],
                  "y": [1, 1],
                  "name": "expected (1σ)", "legendgroup": "one", "showlegend": first, "yaxis": f"y{ax}",
                  "line": {"color": GOOD, "width": 1}, "hoverinfo": "skip"}]
        d = details.get(w.channel, {})
        if "rms_ratio" in d:
            note = (f"{label}: {d['rms_ratio']:.3g}× its expected size after convergence, mean {d['mean']:+.2g}σ;"
                    f" {d['windows_over']} of {d['windows']} windows over the limit ({d['windows_allowed']} allowed)")
            notes.append({"text": note, "xref": "paper", "yref": f"y{ax} domain", "x": 0.01, "y": 1.0,
                          "xanchor": "left", "yanchor": "bottom", "showarrow": False, "font": {"size": 11}})
        decades = float(np.nanmax(w.rms)) > 20 if np.isfinite(w.rms).any() else False
        layout[f"yaxis{ax}"] = {"domain": domains[k], "type": "log", "anchor": "x", **({"dtick": 1} if decades else {}),
                                "title": {"text": f"{label}<br>[σ]", "font": {"size": 11}}}
    layout["annotations"] = notes
    return figure("estimate-innovations", data, layout, height=170 * len(wins) + 80,
                  caption="The block innovations of each channel against the nominal sensor noise, as RMS over 2 s"
                          " windows: 1 when the model and the noise are right; above the dashed limit a window"
                          " counts against the verdict.")


# -- handling ---------------------------------------------------------------------------------------------

def _handling(rep) -> str:
    from online_id.report.handling import section

    est = rep.estimate.result.handling
    fit = getattr(rep.fit, "handling", None) if rep.fit is not None else None
    return _section("handling", "Handling", section(est.to_json_dict() if est is not None else None,
                                                   fit.to_json_dict() if fit is not None else None))


# -- the excitation meter --------------------------------------------------------------------------------

def _excitation(rep) -> str:
    meters = [(m, title) for m, title in ((rep.excitation, "the run's Fisher information (check)"),
                                          (rep.learned, "what the filter learned")) if m is not None]
    run = rep.run
    n = len(meters) + 1
    domains = _stacked_axes(n, gap=0.05)
    t0 = _origin(run)
    layout = {"hovermode": "closest", "xaxis": {"title": {"text": _time_title(t0)}, "anchor": f"y{n}"},
              "yaxis": {"domain": domains[0], "title": {"text": "|a_y| [g]"}, "anchor": "x", "rangemode": "tozero"}}
    data = []
    if run.lateral_acceleration is not None:
        t, a = envelope(run.time - t0, np.abs(run.lateral_acceleration) / G, MAX_POINTS // 2)
        data.append({"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(a), "name": "|a_y|",
                     "showlegend": False, "line": {"width": 1, "color": "#8e44ad"}})
    for k, (m, title) in enumerate(meters, start=2):
        ax = str(k)
        percent = 100 * m.share.T
        z = np.log10(np.clip(percent, METER_FLOOR_PERCENT, 100.0)).round(3)
        ticks = [t for t in (0.1, 1.0, 10.0, 100.0) if t >= METER_FLOOR_PERCENT]
        data.append({"type": "heatmap", "x": arr(m.middle - t0), "y": list(PARAMETER_NAMES), "z": z.tolist(),
                     "customdata": percent.round(3).tolist(), "xaxis": "x", "yaxis": f"y{ax}",
                     "zmin": float(np.log10(METER_FLOOR_PERCENT)), "zmax": 2.0,
                     "colorscale": METER_COLOURS, "showscale": k == 2,
                     "colorbar": {"title": {"text": "% of the<br>run's"}, "len": 0.5, "y": 0.45,
                                  "tickvals": [float(np.log10(t)) for t in ticks],
                                  "ticktext": [f"{t:g}" for t in ticks]},
                     "hovertemplate": "%{y}: %{customdata:.2f} % of " + title + " in the window at %{x:.1f} s"
                                      "<extra></extra>"})
        layout[f"yaxis{ax}"] = {"domain": domains[k - 1], "anchor": "x", "autorange": "reversed",
                                "title": {"text": title.replace(" (", "<br>("), "font": {"size": 11}}}
    inner = [figure("excitation-meter", data, layout, height=560,
                    caption="Where the run taught what. Top: |a_y|. Middle: each window's share of the Fisher"
                            " information on each parameter (how much the inputs there could tell, at the prior,"
                            " with the noise the check measured). Bottom: the share of what the filter actually"
                            " learned in each window (the fall of its log σ: each halving of σ counts the same):"
                            " blank where it froze (above its linear range, under its minimum speed) or where the"
                            " inputs said nothing new.")]
    if rep.excitation is not None:
        inner.append(_bound_figure(rep))
    return _section("excitation", "Excitation meter", "".join(inner))


def _bound_figure(rep) -> str:
    m = rep.excitation
    est = rep.estimate.result
    tr = est.trace
    idx = stride(len(tr.time), MAX_POINTS // 2)
    t0 = _origin(rep.run)
    data = []
    for i, n in enumerate(PARAMETER_NAMES):
        colour = PARAMETER_COLOURS[i]
        data.append({"type": "scatter", "mode": "lines", "x": arr(m.start + m.window_s - t0),
                     "y": arr(100 * m.bound[:, i]),
                     "name": f"{n} bound", "legendgroup": n, "line": {"color": colour, "width": 1.6}})
        rel = tr.std[idx, i] / tr.values[idx, i]
        data.append({"type": "scatter", "mode": "lines", "x": arr(tr.time[idx] - t0), "y": arr(100 * rel),
                     "name": f"{n} filter σ", "legendgroup": n, "showlegend": False,
                     "line": {"color": colour, "width": 1, "dash": "dot"}})
    finite = m.bound[np.isfinite(m.bound) & (m.bound > 0)]
    low = float(np.log10(100 * finite.min())) - 0.2 if finite.size else -2.0
    layout = {"yaxis": {"type": "log", "dtick": 1, "title": {"text": "relative σ [%]"},
                        "range": [low, float(np.log10(BOUND_TOP_PERCENT))]},
              "xaxis": {"title": {"text": _time_title(t0)}}, "hovermode": "x unified"}
    return figure("excitation-bound", data, layout, height=380,
                  caption="The Cramér-Rao bound had the run ended at each moment (solid; it accounts for the"
                          " parameters' correlations) and the filter's own relative σ (dotted). A solid line that"
                          " stays flat: the rest of the run taught nothing more about that parameter.")


# -- the fit ----------------------------------------------------------------------------------------------

def _fit(rep) -> str:
    miss = _not_made(rep, "fit")
    if miss:
        return _section("fit", "The fit", miss)
    f = rep.fit.result
    est = rep.estimate.result
    head = ["param", "estimate", "1σ", "fit", "1σ", "z", ""]
    rows = []
    fv = f.parameters.to_vector()
    for i, n in enumerate(PARAMETER_NAMES):
        a = rep.agreement[n]
        flag = a["disagree"]
        rows.append([f"<td>{n}</td>", f"<td>{fmt(est.parameters.to_vector()[i])}</td>",
                     f"<td>{fmt(est.std[i], 3)}</td>",
                     f'<td class="fit-value" data-param="{n}" data-value="{float(fv[i])!r}">{fmt(fv[i])}</td>',
                     f"<td>{fmt(f.std[i], 3)}</td>",
                     f'<td class="z" data-param="{n}" data-value="{float(a["z"])!r}">{a["z"]:+.2f}</td>',
                     '<td class="flag">DISAGREES</td>' if flag else '<td class="ok">agrees</td>'])
    disagree = ["flag" if rep.agreement[n]["disagree"] else "" for n in PARAMETER_NAMES]
    inner = [table(head, rows, cls="fit", row_classes=disagree),
             '<p class="caption">The batch fit (hybrid GA, then least squares) against the filter: z = difference'
             " in combined σ; |z| > 3 disagrees. " + esc(_sentence(f.choice_reason))
             + f"; {f.evaluations:,} evaluations, {f.wall_s:.1f} s.</p>", verdict_block(f.consistency, "fit")]
    hist = np.asarray(f.ga.history, dtype=float)
    if len(hist):
        line = {"type": "scatter", "mode": "lines+markers" if len(hist) <= 50 else "lines",
                "x": list(range(1, len(hist) + 1)), "y": arr(hist),
                "line": {"color": "#34495e"}, "name": "best cost"}
        inner.append(figure("fit-cost", [line],
                            {"xaxis": {"title": {"text": "GA generation"}}, "yaxis": {"title": {"text": "cost (eq 12)"},
                                                                                    "type": "log"}},
                            height=240, caption="The genetic algorithm's best cost per generation."))
    return _section("fit", "The fit", "".join(inner))


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]


# -- the diagnosis ----------------------------------------------------------------------------------------

def _diagnosis(rep) -> str:
    miss = _not_made(rep, "diagnose")
    if miss:
        return _section("diagnosis", "The diagnosis", miss)
    d = rep.diagnosis.result
    out = d.to_json_dict()
    verdict = d.verdict
    named = verdict or "none: no candidate explains the gap"
    inner = [f'<p class="verdict {"bad" if verdict else "neutral"}">named effect: {esc(named)}</p>',
             f'<p class="muted">held-out data: {esc(d.held_out)}; base model held-out cost'
             f" {d.base_held_out_cost:.4g}</p>"]
    rows = []
    for c, row in zip(d.candidates, out["effects"]):
        params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row["parameters"].items())
        rows.append([f'<td class="text">{esc(c.fit.label)}</td>', f"<td>{c.held_out_cost:.4g}</td>",
                     f'<td data-value="{float(c.reduction)!r}">{100 * c.reduction:.1f} %</td>',
                     f"<td>{c.delta_bic:.0f}</td>",
                     '<td class="ok">yes</td>' if c.significant else "<td>no</td>",
                     f'<td class="text">{esc(params)}</td>'])
    inner.append(table(["effect", "held-out cost", "reduction", "ΔBIC", "significant", "parameters"], rows,
                       cls="diagnosis"))
    if d.how_far:
        inner.append("<p>" + "; ".join(f"{esc(ch)}: held-out RMS error {v['before']:.4g} → {v['after']:.4g}"
                                       for ch, v in d.how_far["channels"].items()) + "</p>")
    for m in d.near_misses:
        came = (f"come to {esc(m['label'])}, {100 * m['reduction']:.1f} % below the base model on held-out data:"
                f" {'a candidate of its own' if m['significant'] else 'not significant either'}" if m["label"]
                else "add nothing significant to it")
        inner.append(f"<p>{esc(m['of'])}: not significant, but it lowers the training BIC: its refinements (below)"
                     f" {came}</p>")
    if d.combination:
        inner.append(f"<p>together: {esc(d.combination['label'])}, {100 * d.combination['reduction']:.1f} % below"
                     " the base model on held-out data</p>")
    for st in d.refinements:
        if "without" in st:
            inner.append(f"<p>without {esc(st['without'])} once refined: it is worth {100 * st['reduction']:.1f} %"
                         f" of held-out cost: {'kept' if st['significant'] else 'dropped'}</p>")
            continue
        if st.get("near_miss"):  # judged against the near miss, which is not what is carried
            inner.append(f"<p>near miss {esc(st['of'])}: refined to {esc(st['label'])}: held-out cost"
                         f" {st['held_out_cost_before']:.4g} → {st['held_out_cost_after']:.4g}"
                         f" ({100 * st['reduction']:.1f} %): {'kept' if st['significant'] else 'not kept'}</p>")
            continue
        inner.append(f"<p>refining {esc(st['of'])} to {esc(st['label'])}: held-out cost"
                     f" {st['held_out_cost_before']:.4g} → {st['held_out_cost_after']:.4g}"
                     f" ({100 * st['reduction']:.1f} %): "
                     f"{'carried instead' if st['significant'] else 'not significant'}</p>")
    if d.carry and d.carry.get("online"):
        flags = " ".join("--effect " + s for s in d.carry["online"])
        inner.append(f"<p>carry it online: <code>{esc(flags)}</code></p>")
    inner.append(_residuals_figure(d, _origin(rep.run)))
    return _section("diagnosis", "The diagnosis", "".join(inner))


def _residuals_figure(d, t0: float = 0.0) -> str:

    s = d.series
    model, held = s["held_model"], s["held"]
    before, after, label = s["base"], s.get("after"), s.get("after_label", "")
    chans = list(model.channels)
    domains = _stacked_axes(len(chans), gap=0.06)
    layout = {"hovermode": "x unified", "legend": {"orientation": "h", "y": 1.1},
              "xaxis": {"title": {"text": _time_title(t0)}, "anchor": f"y{len(chans)}"}}
    data = []
    t_all = model.block_time - t0
    for i, c in enumerate(chans):
        ax = "" if i == 0 else str(i + 1)
        for series, colour, name in ((before, BAD, "base model"), (after, "#1f77b4", f"with {label}")):
            if series is None:
                continue
            y = np.where(held, series[:, i] * model.std[i], np.nan)
            t, y = envelope(t_all, y)
            data.append({"type": "scatter", "mode": "lines", "x": arr(t), "y": arr(y), "name": name,
                         "legendgroup": name, "showlegend": i == 0, "yaxis": f"y{ax}", "connectgaps": False,
                         "line": {"color": colour, "width": 1}})
        layout[f"yaxis{ax}"] = {"domain": domains[i], "anchor": "x", "title": {
            "text": f"{CHANNEL_DISPLAY.get(c, (c,))[0]}<br>[{CHANNEL_UNITS.get(c, '')}]", "font": {"size": 11}}}
    return figure("diagnosis-residuals", data, layout, height=170 * len(chans) + 80,
                  caption=f"Model minus measurement on the held-out data ({esc(d.held_out)}), before and after the"
                          " named effect.")


# -- the commands ------------------------------------------------------------------------------------------

def _commands(rep) -> str:
    if not rep.commands:
        return _section("commands", "Reproduce", '<p class="muted">Made from data in memory: no command line.</p>')
    names = {"check": "what the run can tell", "estimate": "the estimate (and its trace)", "fit": "the batch fit",
             "diagnose": "the diagnosis (and its PNG figures)", "report": "this page"}
    inner = []
    for part, line in rep.commands.items():
        took = f" ({rep.wall_s[part]:.1f} s here)" if part in rep.wall_s else ""
        inner.append(f"<h3>{esc(names.get(part, part))}{esc(took)}</h3><pre class=\"cmd\">{esc(line)}</pre>")
    return _section("commands", "Reproduce", "".join(inner))
