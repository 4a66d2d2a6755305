"""Fitting the base model, or the base model with effects, to the training part of a run.

Residuals are taken on block means of q samples (as in the batch fit, :mod:`online_id.batchfit.cost`),
each channel divided by its measured standard deviation. The block means with effects come from
:class:`~online_id.sim.with_effects.BlockPredictor`: the exact block simulator
(:class:`~online_id.sim.block_means.BlockSimulator`) and each effect's block-mean form
(:meth:`~online_id.effects.base.Effect.block_means`), or for a force-law effect (tyre saturation) a
full-rate simulation (:mod:`online_id.sim.forces`) averaged. Each takes the steering between samples as
``intersample`` says (:mod:`online_id.model.intersample`).
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from online_id.batchfit.cost import COST_CHANNELS
from online_id.batchfit.guarded import guarded_least_squares
from online_id.batchfit.polish import TyreOutputs, beside_tyres
from online_id.effects.base import Effect
from online_id.errors import OnlineIdError
from online_id.filters.prior import unobserved_roll
from online_id.io.tracklog import TrackRun, longitudinal_acceleration_of
from online_id.model.lateral import OUTPUT_NAMES, PARAMETER_NAMES
from online_id.sim import BATCH_INTERSAMPLE
from online_id.sim.with_effects import BlockPredictor
from online_id.stream.samples import block_samples
from online_id.util.threads import THREADS_ENV, fit_threads  # noqa: F401 (scripts and tests import them here)
from online_id.vehicle.loader import Vehicle

#: Samples per block of the residuals.
BLOCK = 10


class BlockModel:
    """Block-mean outputs of the model with effects over one run's inputs.

    Parameters
    ----------
    vehicle : the car
    run : the run (inputs and measured channels)
    block : samples per block
    burn_in_s : leading seconds left out (the simulation starts at rest)
    intersample : the steering between samples (``"hold"``, ``"linear"``, ``"cubic"``)
    """

    def __init__(self, vehicle: Vehicle, run: TrackRun, block: int = BLOCK, burn_in_s: float = 1.0,
                 intersample: str = BATCH_INTERSAMPLE):
        self.vehicle, self.run = vehicle, run
        dts = np.diff(run.time)
        self.dt = float(np.median(dts))
        self.q = block_samples(self.dt, block)  # never more than MAX_BATCH_BLOCK_S: a slow log keeps its content
        if np.any(np.abs(dts - self.dt) > 0.01 * self.dt):
            raise OnlineIdError(f"{run.source}: the diagnosis needs evenly sampled data (steps from"
                                f" {dts.min() * 1e3:.3g} to {dts.max() * 1e3:.3g} ms); resample it first")
        if np.any(np.abs(run.speed) < 1.0):
            raise OnlineIdError(f"{run.source}: the diagnosis needs the car moving (speed under 1 m/s found)")
        if len(run.time) // self.q - int(np.ceil(burn_in_s / (self.dt * self.q))) < 10:
            raise OnlineIdError(f"{run.source}: too short for the diagnosis after a {burn_in_s:g} s burn-in"
                                f" ({len(run.time)} samples)")
        self.channels = tuple(c for c in COST_CHANNELS if getattr(run, c) is not None)
        if not self.channels:
            raise OnlineIdError(f"{run.source}: none of {', '.join(COST_CHANNELS)} to compare with")
        self.cols = [OUTPUT_NAMES.index(c) for c in self.channels]
        ax, self.ax_source = longitudinal_acceleration_of(run)  # where the gap lies: braking, coasting, traction
        self.predictor = BlockPredictor(vehicle.known, run.steering_wheel_angle, run.speed, self.dt, self.q,
                                        intersample=intersample, longitudinal_acceleration=ax)
        self.sim = self.predictor.sim
        n = self.sim.n_used
        self.n_blocks = self.sim.n_blocks
        self.measured = np.column_stack([getattr(run, c)[:n] for c in self.channels]).reshape(
            self.n_blocks, self.q, -1).mean(axis=1)
        self.std = np.array([np.std(getattr(run, c)) for c in self.channels])
        if np.any(self.std <= 0):
            raise OnlineIdError(f"{run.source}: a measured channel is constant; nothing to compare")
        self.block_time = (np.arange(self.n_blocks) + 0.5) * self.q * self.dt + run.time[0]
        self.first_block = int(np.ceil(burn_in_s / (self.dt * self.q)))
        self.steering_blocks = run.steering_wheel_angle[:n].reshape(self.n_blocks, self.q).mean(axis=1)
        self.speed_blocks = run.speed[:n].reshape(self.n_blocks, self.q).mean(axis=1)
        self.ax_blocks = ax[:n].reshape(self.n_blocks, self.q).mean(axis=1)

    def outputs(self, theta, effects: Sequence[Effect] = ()) -> np.ndarray:
        """Block means of the five outputs (n_blocks, 5) with ``effects``."""
        return self.predictor.outputs(theta, effects)

    def residuals(self, theta, effects: Sequence[Effect] = ()) -> np.ndarray:
        """Model minus measurement over every block, divided by each channel's std, (n_blocks, channels)."""
        y = self.outputs(theta, effects)[:, self.cols]
        return (y - self.measured) / self.std


@dataclass
class FamilyFit:
    """The fitted base model with a set of effects."""

    effects: list[Effect]
    theta: np.ndarray
    train_rss: float
    n_train: int
    n_params: int
    evaluations: int
    success: bool
    message: str = ""
    extra: dict = field(default_factory=dict)
    #: the parameters held at ``theta``'s start, not fitted (:func:`unobserved_roll`)
    held: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        return " + ".join(e.label for e in self.effects) or "base model"

    def bic(self) -> float:
        n = self.n_train
        return n * np.log(self.train_rss / n) + self.n_params * np.log(n)

    def aic(self) -> float:
        n = self.n_train
        return n * np.log(self.train_rss / n) + 2 * self.n_params


#: Relative finite-difference step of the fits' Jacobians, on log-scale factors and scaled effect parameters.
DIFF_STEP = 1e-6
#: Relative change of the cost (and of the parameters) at which a fit stops. A relative cost change c moves
#: the BIC by n·c: for the n ≤ 1e5 residuals of a 400 s log at 100 Hz, at most 0.1, a hundredth of
#: MIN_BIC_DROP. A tighter tolerance only spends evaluations creeping along directions the data do not
#: determine (the roll parameters of a log without a roll channel).
FIT_TOLERANCE = 1e-6
#: With a force law (a full-rate simulation per parameter set, which cannot be batched) the Jacobian is
#: recomputed (by finite differences, or for a tyre law from a pass with sensitivities: :data:`EXACT_MIN_COLUMNS`)
#: only every this many iterations and updated in between by Broyden's rank-one secant formula from the steps
#: taken; the fit then ends with a few steps on a Jacobian recomputed at each.
BROYDEN_REFRESH = 5
#: Function evaluations of that final stretch.
FINAL_NFEV = 10


#: A tyre law's fit takes its Jacobian's columns of θ, the μ's and a steering offset from one pass with sensitivities
#: (about three plain passes' cost) when it has at least this many such columns (each a pass by differences); fewer
#: (a screen of one effect's parameters beside the tyres) are differenced.
EXACT_MIN_COLUMNS = 4


#: How far a fit may move each of the 8 parameters from where it starts, in log scale (e^±3: 0.05x-20x).
LOG_RANGE = 3.0


def _held_columns(effects: Sequence[Effect], specs) -> list[int]:
    """Which of a fit's effect parameters ``specs`` ((effect index, FitParameter), in order) the tyre model's pass
    with sensitivities leaves out: the tyre law's beyond its μ's (:attr:`~online_id.effects.base.Effect.held_online`),
    differenced instead."""
    return [k for k, (i, p) in enumerate(specs)
            if effects[i].tyre_mu() is not None and p.name in effects[i].held_online]


def boxed_in(fit: FamilyFit, theta0, start) -> bool:
    """Whether ``fit`` (started at ``theta0``) ended with one of its fitted parameters on the edge of the range
    :data:`LOG_RANGE` around ``theta0``, where a fit started at ``start`` could go further (a base model's fit of a run
    with an effect it lacks can leave ``theta0`` far off: a fit started there is boxed in)."""
    theta, theta0, start = (np.asarray(v, dtype=float) for v in (fit.theta, theta0, start))
    edge = np.exp(LOG_RANGE) * (1.0 - 1e-6)
    for i, name in enumerate(PARAMETER_NAMES):
        if name in fit.held:
            continue
        ratio = theta[i] / theta0[i]
        if ratio >= edge and start[i] * np.exp(LOG_RANGE) > theta[i] * (1.0 + 1e-3):
            return True
        if ratio <= 1.0 / edge and start[i] * np.exp(-LOG_RANGE) < theta[i] * (1.0 - 1e-3):
            return True
    return False


def fit_family(model: BlockModel, train: np.ndarray, theta0, effects: Sequence[Effect] = (),
               max_nfev: int | None = None, free_theta: bool = True, tol: float = FIT_TOLERANCE,
               threads: int | None = None, only_last: bool = False) -> FamilyFit:
    """Least squares over log-scale factors of the 8 parameters around ``theta0`` and the effects'
    parameters, on the blocks selected by the boolean mask ``train``. With ``free_theta=False``
    only the effects' parameters move (a quick screen); with ``only_last`` too, only the last effect's (the others
    held at their values: a screen of one more effect beside those named, which beside the saturating tyres then
    costs no pass of the tyre model, :class:`~online_id.sim.with_effects.BlockPredictor`).

    The Jacobian is by forward differences (relative step :data:`DIFF_STEP`, as scipy's '2-point'),
    but its points are simulated together: every parameter set the columns need is handed to the
    block simulator in one stack (:meth:`~online_id.sim.block_means.BlockSimulator.prefetch`), which shares
    one batched eigen-decomposition per grid speed among them; effect parameters that leave the
    dynamics alone then cost no simulation at all. A force-law effect cannot be batched; there the
    Jacobian is refreshed every :data:`BROYDEN_REFRESH` iterations and Broyden-updated in between, its columns
    simulated side by side on ``threads`` threads (default :func:`fit_threads`: the compiled tyre passes release
    the GIL; each column the same numbers as one by one). A saturating tyre law (with sensor effects or a steering
    offset beside it) takes those refreshes' columns of θ, the μ's and the offset, and every closing step's, from one
    pass with sensitivities (:class:`~online_id.batchfit.polish.TyreOutputs`), the law's other parameters by
    differences meanwhile; ``evaluations`` then counts that pass as one.
    """
    threads = fit_threads() if threads is None else max(1, int(threads))
    tyres_only = all(e.tyre_mu() is not None or e.force_law(theta0, model.vehicle.known) is None for e in effects)
    theta0 = np.asarray(theta0, dtype=float)
    last_effect = len(effects) - 1
    specs = [(i, p) for i, e in enumerate(effects) for p in e.fit_parameters() if not only_last or i == last_effect]
    held = unobserved_roll(model.channels)
    free = [i for i, n in enumerate(PARAMETER_NAMES) if n not in held] if free_theta else []
    n_theta = len(free)
    x0 = np.concatenate([np.zeros(n_theta), [effects[i].values[p.name] / p.scale for i, p in specs]])
    lower = np.concatenate([np.full(n_theta, -LOG_RANGE), [p.lower / p.scale for _, p in specs]])
    upper = np.concatenate([np.full(n_theta, LOG_RANGE), [p.upper / p.scale for _, p in specs]])
    x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)
    counter = [0]

    def unpack(x):
        if n_theta:
            log_scale = np.zeros(len(theta0))
            log_scale[free] = x[:n_theta]
            theta = theta0 * np.exp(log_scale)
        else:
            theta = theta0
        out, k = [], n_theta
        for i, e in enumerate(effects):
            if only_last and i < last_effect:  # (held at its values)
                out.append(e)
                continue
            n = len(e.fit_parameters())
            scales = np.array([p.scale for p in e.fit_parameters()])
            out.append(e.with_vector(x[k:k + n] * scales))
            k += n
        return theta, out

    memo: dict[bytes, np.ndarray] = {}

    def residuals(x):
        theta, effs = unpack(x)
        try:
            r = model.residuals(theta, effs)[train].ravel()
        except OnlineIdError:
            r = np.full(int(train.sum()) * len(model.channels), 1e3)
        return np.where(np.isfinite(r), r, 1e3)

    def fun(x, evaluated=None):
        key = np.asarray(x, dtype=float).tobytes()
        if key in memo:  # least_squares asks for r at the point whose Jacobian it then asks for
            return memo[key]
        counter[0] += 1
        if evaluated is not None and key in evaluated:
            r = evaluated[key]
        else:
            r = with_sensitivities(x, key) if shared and closing[0] and accepted[0] else residuals(x)
            accepted[0] = False  # (until least squares asks for the Jacobian here: it took the step)
        if len(memo) > 4:
            memo.pop(next(iter(memo)))
        memo[key] = r
        return r

    def prefetch(points) -> bool:
        """Simulate the base-model parameter sets of ``points`` together; False for a force law."""
        thetas = []
        for x in points:
            theta, effs = unpack(x)
            if any(e.force_law(theta, model.vehicle.known) is not None for e in effs):
                return False
            for e in effs:
                theta = e.transform_theta(theta, model.vehicle.known)
            thetas.append(theta)
        model.predictor.prefetch(np.array(thetas))
        return True

    last: dict = {}

    def steps(x):
        """The forward differences' steps (relative DIFF_STEP), inside the bounds as scipy's '2-point' keeps them."""
        h = DIFF_STEP * np.maximum(1.0, np.abs(x))
        return np.where(x + h > upper, -h, h)

    def jac(x, broyden=True):
        r0 = fun(x)
        if broyden and last and last["age"] < BROYDEN_REFRESH:
            dx, dr = x - last["x"], r0 - last["r"]
            J = last["J"]
            if dx @ dx > 0:
                J = J + np.outer(dr - J @ dx, dx) / (dx @ dx)
            last.update(x=x.copy(), r=r0, J=J, age=last["age"] + 1)
            return J
        if exact is not None:
            try:
                J = exact_jac(x)
            except OnlineIdError:  # (the pass refused: the columns by differences, as without it)
                J = None
            if J is not None:
                last.update(x=x.copy(), r=r0, J=J, age=1)
                return J
        h = steps(x)
        points = [x] + [x + h[i] * np.eye(len(x))[i] for i in range(len(x))]
        batched = prefetch(points)
        J = np.empty((len(r0), len(x)))
        if not batched and threads > 1 and tyres_only:  # the tyre law: each column's compiled RK4 pass on its own
            # core, the GIL released (the same numbers; another force law's solver keeps a warm start: one by one)
            todo = [p for p in points[1:] if np.asarray(p, dtype=float).tobytes() not in memo]
            with ThreadPoolExecutor(max_workers=threads) as pool:
                done = dict(zip((np.asarray(p, dtype=float).tobytes() for p in todo), pool.map(residuals, todo)))
            # then as fun would have taken them one by one: counted and remembered in order (the same memo after)
            columns = [fun(p, done) for p in points[1:]]
        else:
            columns = [fun(p) for p in points[1:]]
        for i in range(len(x)):
            J[:, i] = (columns[i] - r0) / h[i]
        if not batched:
            last.update(x=x.copy(), r=r0, J=J, age=1)
        return J

    # the saturating tyre law with sensor effects or a steering offset beside it: the Jacobian's columns of θ, the μ's
    # and the offset exact from one pass with sensitivities (TyreOutputs, the polish's model), the law's other
    # parameters (a load exponent, a downforce share) by differences, on the other threads meanwhile: where the
    # Broyden steps refresh their Jacobian and at every closing step (a pass with sensitivities costs about three
    # plain ones: a Jacobian every step would cost more than Broyden's on a fit with a long way to go, the one μ of the
    # race log's two channels 55 steps)
    exact = None
    if beside_tyres(effects, model.vehicle.known):
        held_columns = _held_columns(effects, specs)
        sensors = sum(1 for i, _ in specs if effects[i].stage == "sensor")  # (differenced without a pass)
        if n_theta + len(specs) - len(held_columns) - sensors >= EXACT_MIN_COLUMNS:
            exact = TyreOutputs(model.vehicle, model.run, model.dt, model.q, model.n_blocks, np.inf, np.inf,
                                effects, model.predictor.intersample)
            offsets = np.cumsum([0] + [len(e.fit_parameters()) for e in effects])
            value_columns = [8 + int(offsets[i]) + [q.name for q in effects[i].fit_parameters()].index(p.name)
                             for i, p in specs]
            spec_scales = np.array([p.scale for _, p in specs])

    # the tyre law alone: its pass with sensitivities gives the residuals too (the same block means to round-off), its
    # derivatives kept for the Jacobian least squares asks for next at an accepted point (no pass of their own); only
    # while its steps are taken (after a step turned down, the trust region shrinking, a plain pass a point: about a
    # third of the cost of one with sensitivities, which a point turned down would waste)
    shared = exact is not None and len(effects) == 1
    accepted, closing = [True], [False]
    sensitivities: dict[bytes, np.ndarray] = {}

    def with_sensitivities(x, key):
        theta, effs = unpack(x)
        sensitivities.clear()
        try:
            Y, sensitivities[key] = exact(theta, np.concatenate([e.vector() for e in effs]))
        except OnlineIdError:
            return np.full(int(train.sum()) * len(model.channels), 1e3)
        r = ((Y[:, model.cols] - model.measured) / model.std)[train].ravel()
        return np.where(np.isfinite(r), r, 1e3)

    def exact_jac(x):
        accepted[0] = True
        r0 = fun(x)
        h = steps(x)
        moved = [x + h[n_theta + k] * np.eye(len(x))[n_theta + k] for k in held_columns]
        dY = sensitivities.get(np.asarray(x, dtype=float).tobytes())

        def derivatives():  # (kept from the residuals' pass at this point, else a pass of its own)
            if dY is not None:
                return dY
            theta, effs = unpack(x)
            _, derived = exact(theta, np.concatenate([e.vector() for e in effs]))
            counter[0] += 1
            return derived

        if threads > 1 and moved:  # (the compiled passes release the GIL)
            with ThreadPoolExecutor(max_workers=min(threads - 1, len(moved)) if dY is None else threads) as pool:
                differenced = [pool.submit(residuals, p) for p in moved]
                dY = derivatives()
                differenced = [f.result() for f in differenced]
        else:
            dY = derivatives()
            differenced = [residuals(p) for p in moved]
        counter[0] += len(moved)
        dR = (dY[:, model.cols, :] / model.std[None, :, None])[train].reshape(len(r0), -1)
        J = np.empty((len(r0), len(x)))
        J[:, :n_theta] = dR[:, free]
        J[:, n_theta:] = dR[:, value_columns] * spec_scales
        for k, r in zip(held_columns, differenced):
            J[:, n_theta + k] = (r - r0) / h[n_theta + k]
        return np.where(np.isfinite(J), J, 0.0)

    nfev = max_nfev or 60 * (len(x0) + 1)
    names = [*(PARAMETER_NAMES[i] for i in free), *(f"{effects[i].label} {p.name}" for i, p in specs)]
    what = f"{model.run.source}: the fit of {'the base model' if not effects else ' + '.join(e.label for e in effects)}"
    res = guarded_least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf", x_scale=1.0,
                                max_nfev=nfev, ftol=tol, xtol=tol, what=what, names=names)
    if last:  # Broyden was used: end on fully differenced (or exact) steps
        closing[0] = True
        res = guarded_least_squares(fun, res.x, jac=lambda x: jac(x, broyden=False), bounds=(lower, upper),
                                    method="trf", x_scale=1.0, max_nfev=min(FINAL_NFEV, nfev), ftol=tol, xtol=tol,
                                    what=what, names=names)
    theta, effs = unpack(res.x)
    r = fun(res.x)
    return FamilyFit(effects=effs, theta=theta, train_rss=float(r @ r), n_train=len(r), n_params=len(x0),
                     evaluations=counter[0], success=bool(res.success), message=str(res.message),
                     held=held if free_theta else ())

