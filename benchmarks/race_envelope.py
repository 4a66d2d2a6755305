"""The whole envelope on the real race car: fit on part of the log, judge on the rest (issue 24's acceptance).

Run: python benchmarks/race_envelope.py [LOG] [--split 300] [--variants per_axle,one_mu,linear] [--filters ekf,ukf]

For each variant of the model the EKF and the UKF learn from the log's first ``--split`` seconds exactly as
``online-id estimate LOG --vehicle revs_250lm --effect ...`` does (the same construction: the roll parameters held
without a roll channel, the σ widened for correlated innovations), then the batch polish (the output-error fit
with the same tyre model, ``estimate``'s default final step) refines the EKF's estimate on the same part. Every
estimate is then judged on the held-out rest two ways:

- **open loop**: the model with the estimate, driven by the logged steering and speed from rest over the whole
  log, against the measured yaw rate and a_y on the held-out part (RMS over 0.1 s block means: the a_y
  channel's engine and road vibration at 15-50 Hz averages out);
- **frozen filter**: the same filter with the estimate held (no parameter update) run over the held-out part:
  the RMS of its block innovations, the error of its one-block-ahead prediction (the states are corrected, the
  parameters are not).

Variants: ``per_axle`` (tire_saturation_axles, a μ per axle), ``one_mu`` (tire_saturation), ``linear`` (no tyre
model: the 0.5 g gate leaves half of the log out), and ``per_axle_log_noise`` (each channel learned at the white
noise measured from the log, :func:`online_id.trust.check.noise_floor`, instead of the configured σ: a_y 1.01 m/s²
of vibration against 0.05). Prints one row per filter and variant, and the EKF-UKF-fit disagreement in combined σ.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate  # noqa: E402
from online_id.effects import parse_effect_to_estimate  # noqa: E402
from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.filters.config import FilterConfig  # noqa: E402
from online_id.io.tracklog import read_track_run  # noqa: E402
from online_id.model import tyres  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.trust.check import noise_floor  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters, axle_loads  # noqa: E402

DEFAULT_LOG = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
CHANNELS = ("yaw_rate", "lateral_acceleration")
#: Samples per block of the open-loop comparison (0.1 s at 100 Hz).
BLOCK = 10
#: σ of the held values in the frozen filter: the parameters and μ do not move.
HELD_STD = 1e-6
VARIANTS = {"per_axle": "tire_saturation_axles", "one_mu": "tire_saturation", "linear": None,
            "per_axle_log_noise": "tire_saturation_axles"}


def effects_of(variant: str, values=None) -> list:
    spec = VARIANTS[variant]
    if spec is None:
        return []
    e = parse_effect_to_estimate(spec)
    return [e if values is None else e.with_vector(values)]


def config_for(variant: str, run) -> FilterConfig:
    config = FilterConfig()
    config = dataclasses.replace(config, measurement_std={c: v for c, v in config.measurement_std.items()
                                                          if c in CHANNELS})
    if not variant.endswith("log_noise"):
        return config
    return dataclasses.replace(config, measurement_std={c: max(v, noise_floor(getattr(run, c)))
                                                        for c, v in config.measurement_std.items()})


def mu_values(result, effects) -> list[float]:
    if not effects:
        return []
    e = effects[0]
    entry = result.extra_states["effects"][e.label]
    return [entry[p.name]["value"] for p in e.fit_parameters()]


def mu_text(result, effects) -> str:
    if not effects:
        return "-"
    e = effects[0]
    entry = result.extra_states["effects"][e.label]
    return "/".join(f"{entry[p.name]['value']:.3f}±{entry[p.name]['std']:.3f}" for p in e.fit_parameters())


def open_loop(car, run, theta, effects, mu, split_s) -> tuple[float, float]:
    """Held-out RMS [rad/s, m/s²] of the model run from rest over the whole log (block means)."""
    mu_axles = effects[0].with_vector(mu).tyre_mu() if effects else np.full(2, 1e9)
    delta = np.ascontiguousarray(run.steering_wheel_angle / car.known.steering_ratio)
    _, Y = tyres.rk4_states_and_outputs(np.asarray(theta, float), np.ascontiguousarray(mu_axles, dtype=float),
                                  axle_loads(car.known), delta, np.ascontiguousarray(run.speed),
                                  float(np.median(np.diff(run.time))), tyres.known_array(car.known))
    n = len(run) // BLOCK * BLOCK

    def blocks(x):
        return x[:n].reshape(-1, BLOCK, *x.shape[1:]).mean(axis=1)

    Yb, t = blocks(Y), blocks(run.time)
    held = t >= split_s
    r = np.sqrt(np.mean((Yb[held, 0] - blocks(run.yaw_rate)[held]) ** 2))
    ay = np.sqrt(np.mean((Yb[held, 3] - blocks(run.lateral_acceleration)[held]) ** 2))
    return float(r), float(ay)


def frozen(car, variant, filter_name, config, test, theta, effects, mu) -> dict:
    """Innovation RMS of the filter with the estimate held, over the held-out part."""
    from online_id.effects import tire_saturation

    held_config = dataclasses.replace(config, parameter_random_walk=0.0, converging_random_walk=0.0,
                                      converging_r_scale=1.0, prior_log_std_floor=0.0)
    saved = tire_saturation.MU_PRIOR_STD, tire_saturation.MU_RANDOM_WALK
    tire_saturation.MU_PRIOR_STD, tire_saturation.MU_RANDOM_WALK = HELD_STD, 0.0
    try:
        est = make_estimator(car, filter_name, prior=Parameters.from_vector(theta),
                             prior_relative_std=np.full(len(theta), HELD_STD), config=held_config,
                             effects=effects_of(variant, mu) if effects else [], channels=CHANNELS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run_estimator(est, samples_from_run(test, CHANNELS))
    finally:
        tire_saturation.MU_PRIOR_STD, tire_saturation.MU_RANDOM_WALK = saved
    return res.innovation_rms


def disagreement(a, b) -> dict[str, float]:
    """|a − b| in combined σ per parameter (and μ), for the parameters both report with a σ."""
    out = {}
    for i, n in enumerate(PARAMETER_NAMES):
        sd = np.hypot(a["std"][i], b["std"][i])
        if sd > 0:
            out[n] = abs(a["theta"][i] - b["theta"][i]) / sd
    for k, (va, sa) in a["mu"].items():
        vb, sb = b["mu"][k]
        out[k] = abs(va - vb) / np.hypot(sa, sb)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", type=Path, default=DEFAULT_LOG)
    ap.add_argument("--vehicle", default="revs_250lm")
    ap.add_argument("--split", type=float, default=300.0, help="learn from the first SPLIT seconds [s]")
    ap.add_argument("--variants", default="per_axle,one_mu,linear")
    ap.add_argument("--filters", default="ekf,ukf")
    ap.add_argument("--no-polish", action="store_true")
    args = ap.parse_args()
    car = load_vehicle(args.vehicle)
    run = read_track_run(args.log)
    k = int(np.searchsorted(run.time, run.time[0] + args.split))
    train, test = run.slice(0, k), run.slice(k, len(run))
    split_s = float(run.time[k])
    print(f"{args.log.name}: learn from {train.time[0]:.0f}-{split_s:.0f} s,"
          f" judge on {split_s:.0f}-{run.time[-1]:.0f} s")
    head = (f"{'variant':<24} {'by':<6} {'μ (front/rear)':<24} {'Mzz':>12} {'dyn':>5} {'D1':>15} {'D2':>16}"
            f" {'D/Fz':>11} {'b1':>11} {'b2':>11} {'learned':>8} {'verdict':<7} {'open-loop r, a_y':>17}"
            f" {'frozen r, a_y':>15} {'wall':>6}")
    print(head)
    Fz = axle_loads(car.known)
    for variant in args.variants.split(","):
        effects = effects_of(variant)
        config = config_for(variant, run)
        rows = {}
        for filter_name in args.filters.split(","):
            est = make_estimator(car, filter_name, config=config, effects=effects, channels=CHANNELS)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = run_estimator(est, samples_from_run(train, CHANNELS))
            wall = time.perf_counter() - t0
            rows[filter_name] = res, wall
            if filter_name == "ekf" and effects and not args.no_polish:
                t0 = time.perf_counter()
                polished = dataclasses.replace(res)
                problem = polish_estimate(polished, car, train, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                                          prior_log_std_floor=config.prior_log_std_floor, effects=effects)
                rows["fit"] = (polished, time.perf_counter() - t0) if not problem else (None, problem)
        summary = {}
        for by, (res, wall) in rows.items():
            if res is None:
                print(f"{variant:<24} {by:<6} the polish refused: {wall}")
                continue
            theta = res.parameters.to_vector()
            mu = mu_values(res, effects)
            ol = open_loop(car, run, theta, effects, mu, split_s)
            fr = frozen(car, variant, "ekf" if by == "fit" else by, config, test, theta, effects, mu)
            learned = 1 - (res.events.get("outside_model_range", 0) + res.events.get("outside_linear_range", 0)) / max(
                res.samples, 1)
            dyn = theta[0] / (car.known.M * car.known.l1 * car.known.l2)
            verdict = "—" if by == "fit" else ("ok" if res.consistency["consistent"] else "INCONS")
            sd = res.std
            print(f"{variant:<24} {by:<6} {mu_text(res, effects):<24} {theta[0]:>6.0f}±{sd[0]:<5.0f} {dyn:>5.2f}"
                  f" {theta[2]:>7.0f}±{sd[2]:<7.0f} {theta[3]:>8.0f}±{sd[3]:<7.0f}"
                  f" {theta[2] / Fz[0]:>5.1f}/{theta[3] / Fz[1]:<5.1f} {theta[6]:>5.2f}±{sd[6]:<5.2f}"
                  f" {theta[7]:>5.2f}±{sd[7]:<5.2f} {100 * learned:>7.1f}% {verdict:<7}"
                  f" {ol[0]:>7.4f}, {ol[1]:<7.3f} {fr.get('yaw_rate', np.nan):>6.4f},"
                  f" {fr.get('lateral_acceleration', np.nan):<6.3f}"
                  f" {wall:>5.0f}s")
            e = effects[0] if effects else None
            mus = {}
            if e is not None:
                entry = res.extra_states["effects"][e.label]
                mus = {p.name: (entry[p.name]["value"], entry[p.name]["std"]) for p in e.fit_parameters()}
            summary[by] = {"theta": theta, "std": sd, "mu": mus}
        names = list(summary)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                z = disagreement(summary[a], summary[b])
                worst = max(z, key=z.get) if z else "-"
                print(f"{'':<24} {a}-{b}: largest disagreement {z.get(worst, 0):.1f} combined σ ({worst}); "
                      + " ".join(f"{n} {v:.1f}" for n, v in z.items()))


if __name__ == "__main__":
    main()
