"""Many logs at once: one estimate (and optionally a fit and a diagnosis) per log, on Dask.

:func:`run_batch` sends one task per log to a ``dask.distributed`` cluster (a local one by
default, one worker process per core asked for, one thread each: the work is CPU-bound numpy
on small matrices) and collects, per log, a row of the summary table and a JSON file:

* ``DIR/<key>.json``: ``{"log", "status", "error", "fingerprint", "options", "estimate", "fit",
  "diagnose", "warnings", "wall_s"}``, ``<key>`` being the log's file name made unique with a
  short hash of its absolute path (two ``run.csv`` in different folders do not collide);
* ``DIR/summary.csv``: one row per log given (:data:`SUMMARY_COLUMNS`);
* ``DIR/index.html``: the fleet page, every log's estimate side by side (:mod:`online_id.report.fleet`).

A log that cannot be read or estimated is a ``failed`` row naming the error, never the end of
the batch. A log whose JSON says ``ok`` for the same file (path, size, modification time) and
the same options is not run again: re-running a batch after an interruption, or with logs
added, does only what is missing (``force=True`` runs everything).

The per-log work (:func:`process_log`) is a plain function: the same code runs in a worker
process, in a thread, or inline (``workers=0``, for debugging).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from online_id.util.interrupts import interrupt_inside
from online_id.vehicle.parameters import PARAMETER_NAMES

#: The handling metrics in ``summary.csv``: (column, key of the estimate JSON's ``handling``, factor to the
#: column's unit). Value and ``_std`` columns each; the speed they were taken at in ``handling_speed_mps``.
SUMMARY_HANDLING: tuple[tuple[str, str, float], ...] = (
    ("understeer_gradient_deg_per_g", "understeer_gradient", 1.0),
    ("characteristic_speed_mps", "characteristic_speed", 1.0),
    ("yaw_rate_gain_per_s", "yaw_rate_gain", 1.0),
    ("yaw_natural_frequency_hz", "yaw_natural_frequency", 1.0),
    ("yaw_damping", "yaw_damping", 1.0),
)

#: Columns of ``summary.csv``: the log, its status and error, the samples used, each parameter's
#: value and 1σ (SI units), the consistency verdict (``yes``, ``no`` or ``not judged``, with the reasons or
#: why it was not judged — a run that informed none of its parameters is not judged; empty where the estimate
#: has none), where the log's JSON is, and whether the row was reused from an earlier run of the batch; then
#: (issue 39, added at the end so no column moves) the parameters the run ``informed`` and ``not_informed``
#: (names separated by spaces; a fixed one is in neither), the kind of ``characteristic_speed_mps``
#: (``characteristic``, ``critical`` or ``neutral``), the handling metrics with σ
#: (:data:`SUMMARY_HANDLING`) and the speed they were taken at.
SUMMARY_COLUMNS: tuple[str, ...] = (
    ("log", "status", "error", "samples", "filter")
    + tuple(f"{n}{s}" for n in PARAMETER_NAMES for s in ("", "_std"))
    + ("consistent", "consistency_reasons", "json", "reused")
    + ("informed", "not_informed", "handling_speed_mps", "characteristic_speed_kind")
    + tuple(f"{c}{s}" for c, _, _ in SUMMARY_HANDLING for s in ("", "_std"))
)

#: File that holds the summary in the output folder.
SUMMARY_NAME = "summary.csv"

#: The fleet page in the output folder: every log's estimate side by side (online_id.report.fleet).
INDEX_NAME = "index.html"

#: Hex digits of the path hash that makes a log's JSON name unique.
KEY_HASH_DIGITS = 8


@dataclass(frozen=True)
class BatchOptions:
    """What to do with each log. Plain values only: they travel to the workers and into each JSON."""

    #: the car (a built-in name or a TOML path); None: the default, haro2008, said in each log's warnings
    vehicle: str | None = None
    filter: str = "ekf"
    fit: bool = False
    diagnose: bool = False
    dbc: str | None = None
    signals: str | None = None
    fit_generations: int | None = None
    #: ``--effect`` values (NAME[:CHANNEL][:START]) the estimate carries, and the fit (``fit_effects``: every
    #: effect a diagnosis named, the online ones or not); ``offsets``: the sensor offsets as filter states
    effects: tuple[str, ...] = ()
    fit_effects: tuple[str, ...] = ()
    offsets: bool = False
    #: further keywords of the estimate workflow (:func:`online_id.workflows.estimate_job.estimate`), plain
    #: values: every flag ``online-id estimate`` takes reaches each log (``prior``, ``channels``, ``fixed``, ...)
    estimate: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def estimate_options(self) -> dict:
        """The estimate workflow's keywords for each log."""
        return {"vehicle": self.vehicle, "filter": self.filter, "effects": list(self.effects),
                "offsets": self.offsets, "dbc": self.dbc, "signals": self.signals, **self.estimate}


def log_key(path: str | Path) -> str:
    """A file name for the log's JSON: its name plus a short hash of its absolute path."""
    p = Path(path)
    digest = hashlib.sha1(str(p.resolve()).encode("utf-8")).hexdigest()[:KEY_HASH_DIGITS]
    return f"{p.name}.{digest}"


def fingerprint(path: str | Path) -> dict | None:
    """What identifies the log's content cheaply: absolute path, size [B], modification time [ns]."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return None
    return {"path": str(p.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def process_log(path: str, out_dir: str, options: BatchOptions) -> dict:
    """Estimate (and fit, diagnose) one log; write its JSON; return its summary row.

    Never raises for a bad log: the error becomes ``status: failed`` with a one-line reason.
    """
    from online_id.errors import OnlineIdError
    from online_id.util.threads import single_blas_thread

    t0 = time.perf_counter()
    doc: dict = {"log": str(path), "status": "failed", "error": "", "fingerprint": fingerprint(path),
                 "options": options.to_dict()}
    caught: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as records:
            warnings.simplefilter("always")
            single_blas_thread(_work)(Path(path), options, doc)
        caught = _warning_lines(records)
        doc["status"] = "ok"
    except OnlineIdError as exc:
        doc["error"] = _one_line(str(exc))
    except MemoryError:
        doc["error"] = "out of memory"
    except Exception as exc:  # a bug or a reader we do not know: one line, the batch goes on
        doc["error"] = _one_line(f"{type(exc).__name__}: {exc}")
    doc["warnings"] = caught
    doc["wall_s"] = round(time.perf_counter() - t0, 3)
    json_path = Path(out_dir) / f"{log_key(path)}.json"
    try:
        from online_id.util.jsonio import json_text

        _write_atomic(json_path, json_text(doc))
    except (OSError, TypeError, ValueError) as exc:
        doc["status"] = "failed"
        doc["error"] = _one_line(f"cannot write {json_path}: {exc}")
    return summary_row(doc, json_path)


def _work(path: Path, options: BatchOptions, doc: dict) -> None:
    """The per-log work, through the workflows (the same source layer, checks and defaults as the CLI and
    the API); fills ``doc`` (raises on a bad log)."""
    from online_id import workflows

    decode = {"dbc": options.dbc, "signals": options.signals, "resample": options.estimate.get("resample"),
              "drop_nan": bool(options.estimate.get("drop_nan"))}
    est = workflows.estimate(path, **options.estimate_options())
    if est.result.samples == 0:
        from online_id.errors import OnlineIdError

        raise OnlineIdError(f"{path}: no usable sample")
    doc["estimate"] = est.result.to_json_dict()
    doc["run"] = run_summary(est.result.trace)
    doc["source_warnings"] = list(est.warnings)
    intersample = options.estimate.get("intersample")  # one setting for the estimate, the fit and the diagnosis
    if options.fit:
        doc["fit"] = workflows.fit(path, vehicle=options.vehicle, generations=options.fit_generations,
                                   effects=options.fit_effects, intersample=intersample, **decode).to_json_dict()
    if options.diagnose:
        doc["diagnose"] = workflows.diagnose(path, vehicle=options.vehicle, intersample=intersample,
                                             **decode).result.to_json_dict()


def run_summary(trace) -> dict:
    """Median speed [m/s], peak |a_y| [m/s²] (None where not measured) and duration [s] of an estimate's
    trace: where the fleet page (``index.html``) places the log."""
    speed = trace.speed if trace.speed is not None else np.array([])
    ay = trace.lateral_acceleration if trace.lateral_acceleration is not None else np.array([])
    ay = np.abs(ay[np.isfinite(ay)])
    return {"median_speed_mps": float(np.median(speed)) if len(speed) else None,
            "max_abs_lateral_acceleration_mps2": float(ay.max()) if len(ay) else None,
            "duration_s": float(trace.time[-1] - trace.time[0]) if len(trace.time) > 1 else 0.0}


def summary_row(doc: dict, json_path: Path, reused: bool = False) -> dict:
    """The ``summary.csv`` row of one log's JSON document."""
    est = doc.get("estimate") or {}
    params = est.get("parameters") or {}
    row = {c: "" for c in SUMMARY_COLUMNS}
    row.update(log=doc.get("log", ""), status=doc.get("status", "failed"), error=doc.get("error", ""),
               samples=est.get("samples", 0), filter=est.get("filter", ""), json=str(json_path),
               reused="yes" if reused else "no")
    for n in PARAMETER_NAMES:
        if n in params:
            row[n] = params[n].get("value", "")
            row[f"{n}_std"] = params[n].get("std", "")
    informed, fixed = est.get("informed"), est.get("fixed") or {}
    if isinstance(informed, dict):
        row["informed"] = " ".join(n for n in PARAMETER_NAMES if informed.get(n) and n not in fixed)
        row["not_informed"] = " ".join(n for n in PARAMETER_NAMES if n in informed and not informed[n]
                                       and n not in fixed)
    handling = est.get("handling")
    if isinstance(handling, dict):
        row["handling_speed_mps"] = _number(handling.get("speed_mps"))
        row["characteristic_speed_kind"] = (handling.get("characteristic_speed") or {}).get("kind", "")
        for column, key, factor in SUMMARY_HANDLING:
            entry = handling.get(key) or {}
            row[column] = _number(entry.get("value"), factor)
            row[f"{column}_std"] = _number(entry.get("std"), factor)
    verdict = est.get("consistency")
    if isinstance(verdict, dict):
        row["consistent"] = {True: "yes", False: "no"}.get(verdict.get("consistent"), "not judged")
        row["consistency_reasons"] = "; ".join(str(r) for r in verdict.get("reasons", [])) or str(
            verdict.get("not_judged_because") or "")
    return row


def _number(value, factor: float = 1.0):
    """A float for the summary, "" for none (a σ not determined, a neutral car's characteristic speed)."""
    return "" if value is None else float(value) * factor


def previous_row(path: str, out_dir: Path, options: BatchOptions) -> dict | None:
    """The row of an earlier run of this batch for ``path``, if it ended ok on the same file and options."""
    json_path = out_dir / f"{log_key(path)}.json"
    try:
        doc = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("status") != "ok":
        return None
    if doc.get("fingerprint") != fingerprint(path) or doc.get("options") != options.to_dict():
        return None
    return summary_row(doc, json_path, reused=True)


@dataclass
class BatchResult:
    """Rows in the order the logs were given, the summary's path, and the counts."""

    rows: list[dict]
    summary_path: Path
    wall_s: float
    interrupted: bool = False
    index_path: Path | None = None

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] != "ok"]

    @property
    def reused(self) -> int:
        return sum(r["reused"] == "yes" for r in self.rows)


def run_batch(logs: Sequence[str | Path], out_dir: str | Path, options: BatchOptions | None = None, *,
              workers: int = 2, scheduler: str | None = None, force: bool = False,
              progress: Callable[[int, int, dict], None] | None = None) -> BatchResult:
    """Process ``logs`` on a Dask cluster and write ``out_dir/summary.csv`` plus one JSON per log.

    ``workers``: processes of the local cluster (one thread each); ``0`` runs inline, without
    Dask. ``scheduler``: address of an existing cluster (``tcp://host:8786``), used instead of a
    local one. ``progress(done, total, row)`` is called as each log finishes (reused rows first).
    Ctrl-C (or SIGTERM) cancels what is pending and still writes the summary of what finished;
    the result says ``interrupted``.
    """
    options = options or BatchOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = [str(p) for p in logs]
    rows: dict[int, dict] = {}
    todo: list[int] = []
    for i, p in enumerate(names):
        prev = None if force else previous_row(p, out, options)
        if prev is not None:
            rows[i] = prev
        else:
            todo.append(i)
    total = len(names)
    for i in sorted(rows):
        if progress:
            progress(len([k for k in rows if k <= i]), total, rows[i])
    t0 = time.perf_counter()
    interrupted = False
    try:
        if workers == 0 and scheduler is None:
            for i in todo:
                rows[i] = process_log(names[i], str(out), options)
                if progress:
                    progress(len(rows), total, rows[i])
        elif todo:
            _run_on_dask(names, todo, out, options, workers, scheduler, rows, progress, total)
    except (KeyboardInterrupt, SystemError) as exc:
        if interrupt_inside(exc) is None:  # a SystemError not from a signal in compiled code
            raise
        interrupted = True
    finally:
        for i, p in enumerate(names):
            if i not in rows:
                row = {c: "" for c in SUMMARY_COLUMNS}
                row.update(log=p, status="failed", samples=0, reused="no",
                           error="interrupted before it finished" if interrupted else "not run")
                rows[i] = row
        summary = out / SUMMARY_NAME
        ordered = [rows[i] for i in range(total)]
        _write_atomic(summary, _csv_text(ordered))
        index = _write_index(out, ordered)
    return BatchResult(ordered, summary, time.perf_counter() - t0, interrupted, index)


def _write_index(out: Path, rows: list[dict]) -> Path | None:
    """``index.html``: the fleet page (:mod:`online_id.report.fleet`); None when it could not be written
    (the summary and the JSON are the batch's result: a page it cannot draw does not fail it)."""
    from online_id.report.fleet import render

    path = out / INDEX_NAME
    try:
        _write_atomic(path, render(rows, title=f"online-id batch: {out.name}"))
    except (OSError, ValueError, ImportError) as exc:
        warnings.warn(f"{path}: not written: {exc}", stacklevel=2)
        return None
    return path


def _run_on_dask(names, todo, out, options, workers, scheduler, rows, progress, total) -> None:
    import logging

    from dask.distributed import Client, LocalCluster, as_completed

    if scheduler is not None:
        client = Client(scheduler, timeout="30s")
        cluster = None
    else:
        if workers < 1:
            raise ValueError("workers must be at least 1")
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    try:
        futures = {client.submit(process_log, names[i], str(out), options, pure=False,
                                 key=f"log-{i}-{log_key(names[i])}"): i for i in todo}
        try:
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    row = fut.result()
                except Exception as exc:  # the worker died (KilledWorker), or the task could not run
                    row = {c: "" for c in SUMMARY_COLUMNS}
                    row.update(log=names[i], status="failed", samples=0, reused="no",
                               error=_one_line(f"worker failed: {type(exc).__name__}: {exc}"))
                rows[i] = row
                if progress:
                    progress(len(rows), total, row)
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(SUMMARY_COLUMNS), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: _cell(r.get(c, "")) for c in SUMMARY_COLUMNS})
    return buf.getvalue()


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.9g}"
    return str(v)


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it over ``path``."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _warning_lines(records) -> list[str]:
    """One line per distinct warning, in the tool's words: category and message, no file paths."""
    seen: dict[str, int] = {}
    for r in records:
        line = _one_line(f"{r.category.__name__}: {r.message}")
        seen[line] = seen.get(line, 0) + 1
    return [f"{line} (x{n})" if n > 1 else line for line, n in seen.items()]


def _one_line(text: str) -> str:
    return " ".join(str(text).split())

