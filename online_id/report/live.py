"""The live page of ``online-id listen --web``: served by the listening process itself.

:class:`LiveView` is the listen workflow's ``on_sample(estimator, sample, stats)`` callback. The
estimation loop calls it after every sample; it counts, and reads the filter into a short history every
:data:`READ_PERIOD_S` of wall time and judges it every :data:`VERDICT_PERIOD_S`, whether or not a page is
open. A web server in its own daemon thread answers the page's requests from a copy of that snapshot
taken under a lock held for a list copy: a slow, stalled or closed tab never waits the estimation loop,
and a browser that never connects costs nothing but the snapshot.

Pages: ``/`` (the page), ``/plotly.min.js`` (plotly.js from the ``plotly`` package: no internet),
``/snapshot.json`` (the state the page draws, polled every :data:`REFRESH_MS`).
"""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

from online_id.errors import OnlineIdError
from online_id.report.page import PARAMETER_COLOURS, document, esc, plotly_js
from online_id.util.decimated import DecimatedRows
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS

#: Wall time between two reads of the estimator [s], each a point of the history drawn: 5 a second, twice
#: the page's refresh. Reading the filter costs more than a sample (the EKF brings its grouped steps up to
#: date to answer), so it is read on this clock, never per sample.
READ_PERIOD_S = 0.2
#: Most points of history kept: past it every other point is dropped and points are taken half as often, so
#: a run of hours keeps its whole span evenly (online_id/util/decimated.py), in fixed memory.
MAX_HISTORY = 2000
_N = len(PARAMETER_NAMES)  # a history point: time, the values, their σ, speed
#: Wall time between two verdicts of the live filter [s] (judging reads its whole innovation record).
VERDICT_PERIOD_S = 1.0
#: How often the page asks for a new snapshot [ms]: 2.5 times a second.
REFRESH_MS = 400
#: The address served when only a port is given: this machine only (another host only when asked).
DEFAULT_HOST = "127.0.0.1"


def parse_address(text: str) -> tuple[str, int]:
    """``"8080"`` → (127.0.0.1, 8080); ``"0.0.0.0:8080"`` → ("0.0.0.0", 8080); port 0 picks a free one."""
    host, sep, port = str(text).rpartition(":")
    host = host.strip("[]") if sep else DEFAULT_HOST
    try:
        number = int(port)
    except ValueError:
        raise OnlineIdError(f"--web {text}: expected [HOST:]PORT, e.g. 8080 or 0.0.0.0:8080") from None
    if not 0 <= number <= 65535:
        raise OnlineIdError(f"--web {text}: port must be 0-65535")
    return host or DEFAULT_HOST, number


class LiveView:
    """Snapshot of a live estimate for the page, and the server of the page (see the module docstring)."""

    def __init__(self, name: str = "", host: str = DEFAULT_HOST, port: int = 0):
        self.name, self.host, self.port = name, host, port
        self._lock = threading.Lock()
        self._history = DecimatedRows(MAX_HISTORY, 2 + 2 * _N)  # (t, values (8,), std (8,), speed)
        self._samples = 0
        self._next_read = 0.0
        self._next_verdict = 0.0
        self._state: dict = {"running": True, "samples": 0, "time": None, "verdict": "verdict: not judged yet",
                             "consistent": None, "loss": {}, "ended_by": None}
        self._version = 0
        self._server: ThreadingHTTPServer | None = None
        self._cache: tuple[int, bytes] | None = None

    # -- the estimation loop's side ------------------------------------------------------------------------
    def __call__(self, est, sample, stats=None) -> None:
        """After each sample: a count; every ``READ_PERIOD_S`` of wall time a history point, every
        ``VERDICT_PERIOD_S`` a verdict."""
        self._samples += 1
        now = time.monotonic()
        if now < self._next_read:
            return
        self._next_read = now + READ_PERIOD_S
        values, std = est.parameters.to_vector(), est.parameter_std
        state = {"samples": self._samples, "time": float(sample.time),
                 "speed": float(sample.speed), "values": values.tolist(), "std": std.tolist()}
        if stats is not None:
            state["loss"] = {"lost_samples": int(stats.lost_samples), "frames": int(stats.frames),
                             "lost_fraction": float(stats.loss_fraction()),
                             "by_signal": {k: int(v) for k, v in stats.lost_by_signal.items()}}
        if now >= self._next_verdict:
            from online_id.trust.consistency import judge_estimator, verdict_line

            verdict = judge_estimator(est)
            state.update(verdict=verdict_line(verdict), consistent=verdict["consistent"],  # None: not judged
                         judged=bool(verdict.get("judged", True)))
            self._next_verdict = now + VERDICT_PERIOD_S
        with self._lock:
            self._history.add(_point(sample.time, values, std, sample.speed))
            self._state.update(state)
            self._version += 1

    def finish(self, live) -> None:
        """The run's end: the final estimate, verdict and loss of ``live`` (a
        :class:`~online_id.workflows.results.Listening`), the same numbers as its JSON."""
        from online_id.trust.consistency import verdict_line

        r = live.result
        values, std = r.parameters.to_vector(), np.asarray(r.std, dtype=float)
        with self._lock:
            if len(r.trace.time):
                t = float(r.trace.time[-1])
                last = self._history.last
                if last is None or last[0] < t:
                    self._history.add(_point(t, values, std, self._state.get("speed") or 0.0))
                self._state["time"] = t
            loss = live.loss
            self._state.update(running=False, ended_by=live.ended_by, samples=int(r.samples), values=values.tolist(),
                               std=std.tolist(), verdict=verdict_line(r.consistency),
                               consistent=(r.consistency or {}).get("consistent"),
                               loss={"lost_samples": loss.get("lost_samples", 0),
                                     "frames": loss.get("frames_received", 0),
                                     "lost_fraction": loss.get("lost_samples_fraction", 0.0),
                                     "by_signal": dict(loss.get("lost_by_signal", {}))})
            self._version += 1

    # -- the server's side -----------------------------------------------------------------------------------
    def snapshot(self) -> dict:
        """What the page draws: the state, the history as columns, and the filter's excitation meter."""
        from online_id.trust.over_time import learned_by_window

        with self._lock:
            history = self._history.rows()
            state = dict(self._state)
        out = {"name": self.name, "parameters": list(PARAMETER_NAMES), "units": PARAMETER_UNITS, **state}
        if len(history):
            t, v, s = history[:, 0], history[:, 1:1 + _N], history[:, 1 + _N:1 + 2 * _N]
            out["history"] = {"time": _round(t), "values": [_round(v[:, i]) for i in range(v.shape[1])],
                              "std": [_round(s[:, i]) for i in range(s.shape[1])]}
            meter = learned_by_window(t, v, s)
            out["meter"] = {"middle": _round(meter.middle), "window_s": meter.window_s,
                            "share": [_round(100 * meter.share[:, i], 3) for i in range(meter.share.shape[1])]}
        return out

    def snapshot_bytes(self) -> bytes:
        version = self._version
        if self._cache is None or self._cache[0] != version:
            self._cache = (version, json.dumps(self.snapshot(), separators=(",", ":")).encode("utf-8"))
        return self._cache[1]

    def page(self) -> str:
        return live_page(self.name)

    def start(self) -> str:
        """Serve the page from a daemon thread; returns its address (``http://host:port/``)."""
        view = self
        page = self.page().encode("utf-8")

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 - the name http.server calls
                path = self.path.split("?")[0]
                if path in ("/", "/index.html"):
                    self._send(page, "text/html; charset=utf-8")
                elif path == "/plotly.min.js":
                    self._send(_plotly_bytes(), "text/javascript; charset=utf-8", cache=True)
                elif path == "/snapshot.json":
                    self._send(view.snapshot_bytes(), "application/json")
                elif path == "/favicon.ico":  # asked for by every browser: none, without an error in its console
                    self.send_response(204)
                    self.end_headers()
                else:
                    self.send_error(404)

            def _send(self, body: bytes, kind: str, cache: bool = False):
                try:
                    self.send_response(200)
                    self.send_header("Content-Type", kind)
                    self.send_header("Content-Length", str(len(body)))
                    self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
                    self.end_headers()
                    self.wfile.write(body)
                except (BrokenPipeError, ConnectionResetError):  # a tab closed mid-answer: nothing to do
                    pass

            def log_message(self, format, *args):  # noqa: A002 - http.server's signature; no access log
                pass

        class Server(ThreadingHTTPServer):
            daemon_threads = True

            def handle_error(self, request, client_address):  # a broken client never prints a traceback
                pass

        try:
            self._server = Server((self.host, self.port), Handler)
        except OSError as exc:
            raise OnlineIdError(f"--web {self.host}:{self.port}: cannot serve the live page: {exc.strerror or exc}") \
                from None
        thread = threading.Thread(target=self._server.serve_forever, name="online-id live page", daemon=True)
        thread.start()
        host, port = self._server.server_address[:2]
        shown = f"[{host}]" if ":" in str(host) else host
        return f"http://{shown}:{port}/"

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None


def _point(t, values, std, speed) -> np.ndarray:
    """A history point: (time, values (8,), std (8,), speed)."""
    return np.concatenate(([float(t)], values, std, [float(speed)]))


def _round(a, digits: int = 6) -> list:
    return [float(f"{x:.{digits}g}") if np.isfinite(x) else None for x in np.asarray(a, dtype=float).tolist()]


_PLOTLY: list[bytes] = []


def _plotly_bytes() -> bytes:
    if not _PLOTLY:
        _PLOTLY.append(plotly_js().encode("utf-8"))
    return _PLOTLY[0]


def live_page(name: str) -> str:
    """The live page (its script polls ``/snapshot.json``)."""
    rows = "".join(f'<tr><td style="color:{PARAMETER_COLOURS[i]}">{n}</td><td class="text">{esc(PARAMETER_UNITS[n])}'
                   f'</td><td class="value" data-param="{n}">—</td><td class="std" data-param="{n}">—</td>'
                   f'<td class="rel" data-param="{n}">—</td></tr>' for i, n in enumerate(PARAMETER_NAMES))
    body = (f'<header class="top"><h1>online-id listen: {esc(name)}</h1><div class="sub"><span id="status">'
            'waiting for the first snapshot</span></div></header><main>'
            '<div class="cards"><div class="card"><div class="k">stream time</div>'
            '<div class="v" id="time">—</div></div>'
            '<div class="card"><div class="k">samples</div><div class="v" id="samples" data-value="0">0</div></div>'
            '<div class="card"><div class="k">speed</div><div class="v" id="speed">—</div></div>'
            '<div class="card"><div class="k">samples lost</div><div class="v" id="lost">0</div></div>'
            '<div class="card"><div class="k">page updates</div><div class="v" id="updates">0</div></div></div>'
            '<p class="verdict neutral" id="verdict">verdict: not judged yet</p>'
            '<div class="grid2"><div><h3>Estimate</h3><table class="estimate"><thead><tr><th>param</th>'
            '<th class="text">unit</th><th>value</th><th>1σ</th><th>1σ %</th></tr></thead>'
            f'<tbody>{rows}</tbody></table></div><div><h3>Samples lost per signal</h3>'
            '<table class="loss"><thead><tr><th>signal</th><th>lost</th></tr></thead><tbody id="loss-rows">'
            '<tr><td>none yet</td><td>0</td></tr></tbody></table></div></div>'
            '<h3>Parameters over time (±1σ)</h3>'
            '<div class="plot" id="live-trajectories" style="min-height:780px"></div>'
            '<h3>Excitation meter: where the filter learned</h3><div class="plot" id="live-meter"'
            ' style="min-height:300px"></div><p class="caption">Each window\'s share of the information the filter'
            ' learned on each parameter so far (the fall of its log σ): blank where it learned nothing.</p></main>')
    config = json.dumps({"refresh_ms": REFRESH_MS, "colours": PARAMETER_COLOURS, "units": PARAMETER_UNITS})
    script = f"window.LIVE = {config};\n" + _asset("live.js")
    return document(f"online-id listen: {name}", body, script=script, plotly="/plotly.min.js")


def _asset(name: str) -> str:
    from online_id.report.page import asset

    return asset(name)
