"""The pieces every page shares: the self-contained HTML document (its style and plotly.js inside it),
figures as plotly.js specifications, tables, and thinning a long series to what a page can draw.

Why plotly.js (through the ``plotly`` package, which ships its minified bundle, ``get_plotlyjs()``): one
library draws all three pages from plain JSON specifications, so the Python side builds dicts from result
objects and never imports a plotting layer; a live page redraws the same specifications with
``Plotly.react`` from a JSON snapshot, without a server framework; it draws SVG with zoom, hover and
a PNG export built in, works offline, and is MIT-licensed and actively released. matplotlib stays for
the PNG figures (``--plot``, ``diagnose --report``, ``plot convergence``).
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Iterable, Sequence
from functools import cache
from importlib import resources

import numpy as np

#: Points a line on a page is thinned to: a 400 s log at 100 Hz is 40,000 rows; the screen shows ~1,500
#: pixels across, and the 10 MB budget of a report holds plotly.js (4.8 MB) and about 40 such lines.
MAX_POINTS = 1500
#: Significant digits of the numbers drawn (not of those shown in tables): finer than a pixel.
PLOT_DIGITS = 5
#: One colour per parameter, the same on every page and figure (plotly's qualitative "D3" set).
PARAMETER_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf")
#: The colours of a verdict (WARN: a run that informed nothing, neither a result nor a failure).
GOOD, BAD, NEUTRAL, WARN = "#2a7d2a", "#c0392b", "#777777", "#b9770e"


@cache
def plotly_js() -> str:
    """plotly.js, minified, as the ``plotly`` package ships it (no network)."""
    from plotly.offline import get_plotlyjs

    return get_plotlyjs()


@cache
def asset(name: str) -> str:
    """A file of ``online_id/report/assets`` (the pages' style and scripts)."""
    return resources.files("online_id.report").joinpath("assets", name).read_text(encoding="utf-8")


def inline_script(code: str) -> str:
    """``code`` in a script element (a ``</`` inside it could end the element early)."""
    return "<script>" + code.replace("</", "<\\/") + "</script>"


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def fmt(value, digits: int = 5) -> str:
    """A number for a table: ``digits`` significant digits, whole numbers from 10,000 to 10⁹ with thousands
    separators (no "1.1196e+05" for a cornering stiffness), "—" for none or NaN."""
    if value is None:
        return "—"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return esc(value)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "∞" if v > 0 else "-∞"
    if min(1e4, 10.0 ** digits) <= abs(v) < 1e9:
        return f"{float(f'{v:.{digits}g}'):,.0f}"
    return f"{v:.{digits}g}"


def arr(values, digits: int = PLOT_DIGITS) -> list:
    """A numeric array as a JSON list, rounded to ``digits`` significant digits, NaN/inf as null (a gap)."""
    a = np.asarray(values, dtype=float).ravel()
    out = []
    for x in a.tolist():
        out.append(float(f"{x:.{digits}g}") if math.isfinite(x) else None)
    return out


def stride(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of every k-th of ``n`` points (and the last) so that at most ``max_points`` remain."""
    if n <= max_points:
        return np.arange(n)
    idx = np.arange(0, n, int(math.ceil(n / max_points)))
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A noisy series thinned to ``max_points`` keeping each bucket's lowest and highest value, in time
    order, so peaks (a spike, 1.7 g in a hairpin) survive the thinning a stride would lose."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    n = len(t)
    if n <= max_points:
        return t, y
    buckets = max_points // 2
    edges = np.linspace(0, n, buckets + 1).astype(int)
    keep = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        seg = y[lo:hi]
        if hi <= lo:
            continue
        if not np.isfinite(seg).any():
            keep.append(lo)
            continue
        a, b = lo + int(np.nanargmin(seg)), lo + int(np.nanargmax(seg))
        keep += sorted({a, b})
    keep = np.array(keep)
    return t[keep], y[keep]


def figure(element_id: str, data: list[dict], layout: dict, height: int = 320, caption: str = "") -> str:
    """A figure's element: a ``div.plot`` holding its plotly.js specification (drawn by the page's script)."""
    spec = json.dumps({"data": data, "layout": {"height": height, "margin": {"l": 70, "r": 20, "t": 30, "b": 40},
                                                 "font": {"size": 12}, **layout}},
                      separators=(",", ":"), allow_nan=False)
    spec = spec.replace("</", "<\\/")
    cap = f'<p class="caption">{caption}</p>' if caption else ""
    return (f'<div class="figure"><div class="plot" id="{esc(element_id)}" style="min-height:{height}px"></div>'
            f'<script type="application/json" class="plot-spec" data-for="{esc(element_id)}">{spec}</script>'
            f'{cap}</div>')


def table(head: Sequence[str], rows: Iterable[Sequence[str]], cls: str = "", raw: bool = True,
          row_classes: Sequence[str] | None = None) -> str:
    """An HTML table (scrolling sideways when wider than the page); cells are HTML already (``raw``: a
    ``<td ...>`` element, or its content) or text to escape; ``row_classes`` per row (``"flag"``, ``"dim"``)."""
    def cell(c):
        return c if raw else esc(c)

    rows = list(rows)
    classes = list(row_classes) if row_classes is not None else [""] * len(rows)
    h = "".join(f"<th>{cell(c)}</th>" for c in head)
    body = "".join((f'<tr class="{esc(k)}">' if k else "<tr>")
                   + "".join(c if raw and str(c).startswith("<td") else f"<td>{cell(c)}</td>" for c in r) + "</tr>"
                   for r, k in zip(rows, classes))
    return (f'<div class="table-wrap"><table class="{esc(cls)}"><thead><tr>{h}</tr></thead><tbody>{body}</tbody>'
            "</table></div>")


def verdict_block(consistency: dict | None, what: str = "verdict") -> str:
    """The verdict as a coloured line (green consistent, red inconsistent, grey not judged: ``consistent``
    null, a run too short to test) and its reasons as a list; ``data-consistent`` is true, false or null."""
    from online_id.trust.consistency import verdict_line

    if consistency is None:
        return f'<p class="verdict neutral" data-consistent="null">{esc(what)}: not judged</p>'
    ok = consistency.get("consistent")
    state = "true" if ok is True else "false" if ok is False else "null"
    cls = {"true": "good", "false": "bad", "null": "neutral"}[state]
    head = verdict_line(consistency).split(" — ")[0].removeprefix("verdict: ")
    lines = list(consistency.get("reasons", []))
    if consistency.get("not_judged_because"):
        lines.append(f"not judged: {consistency['not_judged_because']}")
    reasons = "".join(f"<li>{esc(r)}</li>" for r in lines)
    return (f'<p class="verdict {cls}" data-consistent="{state}">{esc(what)}: {esc(head)}</p>'
            + (f'<ul class="reasons">{reasons}</ul>' if reasons else ""))


def document(title: str, body: str, *, script: str = "", plotly: str = "inline") -> str:
    """The whole page: the style, plotly.js (``inline``; or a path the page's server serves), the body, and
    the script that draws every ``div.plot`` from its specification."""
    lib = inline_script(plotly_js()) if plotly == "inline" else f'<script src="{esc(plotly)}"></script>'
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{esc(title)}</title><style>{asset('page.css')}</style>{lib}</head>"
            f"<body>{body}{inline_script(asset('plots.js'))}{inline_script(script) if script else ''}</body></html>\n")
