"""A long run's pass of the saturating-tyre model in two pieces, one on each core (issue 40).

A pass of :mod:`online_id.model.tyres` over a whole run (the batch fits' and the diagnosis's model with tyres, the
polish's pass with sensitivities) is one trajectory from rest, sample after sample: it keeps one core busy, and a
race log's diagnosis is most of its time in such passes, one after another. The car forgets where it started: its
slowest mode decays at a few per second (the race car's yaw-sideslip mode, 4/s at 45 m/s), so a trajectory started
from rest :data:`OVERLAP_S` before a point of the run is there the whole run's to e^(−4·10) of its size. So:

1. the first piece is the run's first half, from rest, as the whole pass computes it (the same numbers);
2. the second piece starts from rest :data:`OVERLAP_S` before the half, on another core meanwhile;
3. where they meet, the second piece's state (and its sensitivities) must be the first's to :data:`MATCH_TOL` of
   the run's scale. If so, the second piece's samples from the half on are kept; if not (a slower mode; a car at its
   limit that does not forget at all, as the race car's filter estimate carried to the polish; one that spins), the
   run is simulated again from the first piece's state, the whole pass's continuation bit for bit, :data:`CHUNK_S`
   at a time, until the second piece's state meets it; after :data:`CHUNKS_TRIED` stretches (or at once, where the
   pieces first differ by more than :data:`HOPELESS`), to the run's end.

Runs shorter than :data:`MIN_RUN_S` are one piece. The split depends on the run alone, never on the number of
threads (``ONLINE_ID_FIT_THREADS`` = 1 computes the same two pieces one after the other): a fit's answer does not
depend on the machine.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from online_id.model import tyres
from online_id.util.threads import fit_threads

#: Runs shorter than this [s] are simulated in one piece (the overlap would be a large share of each).
MIN_RUN_S = 60.0
#: The second piece starts from rest this long [s] before the samples it gives.
OVERLAP_S = 10.0
#: Where the pieces meet, the second's state must be the first's to this share of the largest state (and its
#: sensitivities of the largest sensitivity); else the run is simulated again from the first's state, :data:`CHUNK_S`
#: at a time, until the second piece meets that.
MATCH_TOL = 1e-12
#: The stretch [s] simulated again at a time where the pieces do not meet.
CHUNK_S = 5.0
#: Stretches tried before the rest of the run is simulated again in one go: a model that has not forgotten its start
#: after the overlap and 15 s more does not forget it (the race car's filter estimate at its limit: the state the
#: second piece started from still shows at 1e-4 rad/s to the end).
CHUNKS_TRIED = 3
#: Where the pieces first meet, a difference above this share of the scale is not tried in stretches at all: 15 s
#: more of a mode that forgets at 1/s would take it down by 3e-7 (the race car's filter estimate: 5e-4).
HOPELESS = 1e-6

_pool: ThreadPoolExecutor | None = None
#: Threads computing a pass or a piece now (every caller's and the pieces' own): a second piece goes to another core
#: only while one is free (the diagnosis's screens side by side, a fit's Jacobian columns on threads: each their
#: core already, and a second piece would queue behind another's); else it is computed after the first, here. The
#: numbers are the same either way: the split is the run's.
_busy = 0
_lock = threading.Lock()


class _Busy:
    """One thread computing (entered by each caller of the passes below, and by a second piece on its core)."""

    def __enter__(self):
        global _busy
        with _lock:
            _busy += 1

    def __exit__(self, *exc):
        global _busy
        with _lock:
            _busy -= 1


def _second_core(work):
    """``work()`` on the pieces' own thread when a core is free (a future), else a promise to compute it here when
    its result is asked for (after the first piece)."""
    global _pool, _busy
    cores = fit_threads()
    with _lock:
        free = _busy < cores
        if free:
            _busy += 1  # (the piece's, from now: it is counted before it starts)
            if _pool is None:
                _pool = ThreadPoolExecutor(max_workers=max(1, cores - 1), thread_name_prefix="online-id-piece")
    if not free:
        return _Later(work)

    def counted():
        global _busy
        try:
            return work()
        finally:
            with _lock:
                _busy -= 1

    return _pool.submit(counted)


class _Later:
    def __init__(self, work):
        self.work = work

    def result(self):
        return self.work()


def split_points(n: int, dt: float, q: int = 1) -> tuple[int, int] | None:
    """Where the second piece's kept samples begin and where it starts from rest (sample indices, multiples of
    ``q``), for a run of ``n`` samples every ``dt`` [s]; None: one piece."""
    if n * dt < MIN_RUN_S:
        return None
    half = (n // 2) // q * q
    back = math.ceil(OVERLAP_S / dt / q) * q
    return half, max(0, half - back)


def _close(a, b, scale, tol=None) -> bool:
    """|a − b| within ``tol`` (default :data:`MATCH_TOL`) of ``scale`` (a number, or one a column of a and b)."""
    return bool(np.all(np.abs(a - b) <= (MATCH_TOL if tol is None else tol) * np.maximum(scale, 1e-300)))


def states_and_outputs(theta, mu, Fz, W, speeds, dt, kn):
    """:func:`online_id.model.tyres.rk4_states_and_outputs_input` of a whole run (its arguments), in two pieces
    (module docstring)."""
    n = W.shape[0]
    split = split_points(n, dt)
    if split is None:
        return tyres.rk4_states_and_outputs_input(theta, mu, Fz, W, speeds, dt, kn)
    half, start = split
    with _Busy():
        return _states_and_outputs(theta, mu, Fz, W, speeds, dt, kn, n, half, start)


def _states_and_outputs(theta, mu, Fz, W, speeds, dt, kn, n, half, start):
    second = _second_core(lambda: tyres.states_and_outputs_from(theta, mu, Fz[start:], W[start:], speeds[start:],
                                                                 dt, kn, np.zeros(6)))
    # (to the half's sample inclusive: the step into it takes the loads of both its ends, as the whole pass does)
    states1, Y1 = tyres.states_and_outputs_from(theta, mu, Fz[:half + 1], W[:half + 1], speeds[:half + 1], dt, kn,
                                                np.zeros(6))
    states2, Y2 = second.result()
    scale = np.max(np.abs(states1), initial=0.0)
    states, Y = [states1[:half]], [Y1[:half]]
    k, x, chunk = half, states1[half].copy(), max(1, math.ceil(CHUNK_S / dt))
    tries = 0 if _close(states2[k - start], x, scale, HOPELESS) else CHUNKS_TRIED
    while not _close(states2[k - start], x, scale):  # the whole pass's continuation until the second piece meets it
        tries += 1
        end = min(n, k + chunk) if tries <= CHUNKS_TRIED else n  # (then to the end in one go)
        stop = min(n, end + 1)
        s, y = tyres.states_and_outputs_from(theta, mu, Fz[k:stop], W[k:stop], speeds[k:stop], dt, kn, x)
        states.append(s[:end - k])
        Y.append(y[:end - k])
        if end == n:
            return np.concatenate(states), np.concatenate(Y)
        k, x = end, s[end - k].copy()
    states.append(states2[k - start:])
    Y.append(Y2[k - start:])
    return np.concatenate(states), np.concatenate(Y)


def blocks(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift=0.0, shift_column=False):
    """:func:`online_id.model.tyres.simulate_blocks_input` of a whole run (its arguments), in two pieces that meet
    at a block's edge (module docstring): the block means and their derivatives."""
    n = (W.shape[0] // q) * q
    split = split_points(n, dt, q)
    if split is None:
        return tyres.simulate_blocks_input(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift, shift_column)
    half, start = split
    with _Busy():
        return _blocks(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift, shift_column, n, half, start)


def _blocks(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift, shift_column, n, half, start):
    n_par = tyres.N_PARAMS + mu_columns + (1 if shift_column else 0)
    x0, S0 = np.zeros(tyres.N_STATES), np.zeros((tyres.N_STATES, n_par))
    chunk = max(1, math.ceil(CHUNK_S / dt / q)) * q
    marks = np.arange(half - start, n - start, chunk, dtype=np.int64)  # (where each stretch simulated again ends)
    second = _second_core(lambda: tyres.blocks_from(theta, mu, Fz[start:], W[start:], speeds[start:], dt, kn, q,
                                                    mu_columns, shift, shift_column, x0, S0, marks, (n - start) // q))
    # (one sample past the half, not in a block: the step into the half takes the loads of both its ends)
    none = np.zeros(0, dtype=np.int64)
    Y1, dY1, _, _, x, S = tyres.blocks_from(theta, mu, Fz[:half + 1], W[:half + 1], speeds[:half + 1], dt, kn, q,
                                            mu_columns, shift, shift_column, x0, S0, none, half // q)
    Y2, dY2, x_marks, S_marks, _, _ = second.result()
    scale_x = max(np.max(np.abs(x)), np.max(np.abs(Y1[:, :3]), initial=0.0))
    # (each sensitivity against its own column's scale: a steering offset's is radians' size, a relaxation length's
    # may be a millionth of it)
    scale_S = np.maximum(np.max(np.abs(S), axis=0), np.max(np.abs(dY1[:, :3, :]), axis=(0, 1), initial=0.0))
    Y, dY = [Y1[:half // q]], [dY1[:half // q]]
    k, j = half, 0
    tries = 0 if _close(x_marks[0], x, scale_x, HOPELESS) and _close(S_marks[0], S, scale_S, HOPELESS) else CHUNKS_TRIED
    while not (_close(x_marks[j], x, scale_x) and _close(S_marks[j], S, scale_S)):  # (as states_and_outputs)
        tries += 1
        end = min(n, k + chunk) if tries <= CHUNKS_TRIED else n
        stop = min(W.shape[0], end + 1)
        y, dy, _, _, x, S = tyres.blocks_from(theta, mu, Fz[k:stop], W[k:stop], speeds[k:stop], dt, kn, q, mu_columns,
                                              shift, shift_column, x, S, none, (end - k) // q)
        Y.append(y[:(end - k) // q])
        dY.append(dy[:(end - k) // q])
        if end == n:
            return np.concatenate(Y), np.concatenate(dY)
        k, j = end, j + 1
    Y.append(Y2[(k - start) // q:])
    dY.append(dY2[(k - start) // q:])
    return np.concatenate(Y), np.concatenate(dY)
