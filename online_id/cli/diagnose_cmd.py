"""``online-id diagnose``: where the base model misses, which unmodelled effect causes it, how far
the gap shrinks with it, on data the fit did not see."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from online_id.cli import library_warnings, termination
from online_id.cli.common import add_intersample_argument, log_parent, printed_messages, source_options
from online_id.cli.estimate_cmd import input_paths
from online_id.cli.outputs import Outputs, json_text
from online_id.cli.plausibility_args import add_plausibility_argument
from online_id.diagnosis import MIN_BIC_DROP, MIN_REDUCTION
from online_id.diagnosis.kinematics import kinematics_line
from online_id.effects import DIAGNOSIS_CANDIDATES, EFFECTS
from online_id.stream.samples import MEASURED_CHANNELS


def add_parser(sub) -> None:
    p = sub.add_parser(
        "diagnose",
        parents=[log_parent()],
        description="Fit the base model to LOG, locate its errors by frequency, amplitude and time, fit each"
        f" candidate effect ({', '.join(EFFECTS)}), and rank them by the gap left on data the fits did not"
        " see (--validate LOG2, or held-out segments of LOG). An effect is significant when it lowers the"
        f" training BIC by more than {MIN_BIC_DROP:g} and the held-out cost by at least"
        f" {100 * MIN_REDUCTION:g} %. With no LOG, the built-in run is used.",
    )
    p.add_argument("--validate", type=Path, metavar="LOG2", help="a second run to judge the fits on")
    p.add_argument("--effects", help=f"comma-separated candidates to try, of {','.join(EFFECTS)} (default:"
                   f" {','.join(DIAGNOSIS_CANDIDATES)}: a refinement of another only when asked)")
    p.add_argument("--channels", metavar="LIST",
                   help="comma-separated measured channels to judge the model on (default: all present of"
                   f" {','.join(MEASURED_CHANNELS)})")
    add_intersample_argument(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the diagnosis as JSON")
    p.add_argument("--report", type=Path, metavar="DIR", help="write the report figures into DIR")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_plausibility_argument(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.workflows import diagnose

    Outputs.check({"--json": args.json, "--report": args.report}, input_paths(args), folders=("--report",))
    d = diagnose(args.log, vehicle=args.vehicle, validate=args.validate, effects=args.effects, channels=args.channels,
                 allow_implausible=args.allow_implausible, resample=args.resample, intersample=args.intersample,
                 progress=not args.quiet, messages=printed_messages(), **source_options(args)).result
    out = d.to_json_dict()
    print(f"held-out data: {d.held_out}; base model held-out cost {d.base_held_out_cost:.4g}")
    if d.base.held:
        print(f"no roll channel: {', '.join(d.base.held)} held at the prior in every fit (the data barely inform them)")
    print(f"{'effect':<40} {'after':>9} {'reduction':>9} {'ΔBIC':>10}  significant  parameters")
    for c, row in zip(d.candidates, out["effects"]):
        params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row["parameters"].items())
        print(f"{c.fit.label:<40} {c.held_out_cost:>9.4g} {100 * c.reduction:>8.1f}% {c.delta_bic:>10.0f}"
              f"  {'yes' if c.significant else 'no (bound)' if c.at_bound else 'no ':<11}  {params}")
    for f in d.failed:  # the others stand
        print(f"online-id: warning: {f['name']} failed in {f['stage']}: {f['error']}", file=sys.stderr)
    for line in near_miss_lines(d.near_misses):
        print(line)
    print(f"verdict: {d.verdict or 'no candidate explains the gap'}")
    if d.how_far:
        for ch, v in d.how_far["channels"].items():
            print(f"  {ch}: held-out RMS error {v['before']:.4g} -> {v['after']:.4g} (ratio {v['ratio']:.3f})")
    if d.combination:
        for st in d.combination["steps"]:
            print(f"adding {st['label']}: held-out cost {st['held_out_cost_before']:.4g} ->"
                  f" {st['held_out_cost_after']:.4g} ({100 * st['reduction']:.1f}%, ΔBIC {st['delta_bic']:.0f}):"
                  f" {'kept' if st['significant'] else 'not significant'}")
        print(f"together: {d.combination['label']}, {100 * d.combination['reduction']:.1f}% below the base model"
              " on held-out data")
    for st in d.refinements:
        if "without" in st:  # a named effect checked again once a refinement was kept
            print(f"without {st['without']} once refined: held-out cost {st['held_out_cost_before']:.4g} ->"
                  f" {st['held_out_cost_after']:.4g} (it is worth {100 * st['reduction']:.1f}%, ΔBIC"
                  f" {st['delta_bic']:.0f}): {'kept' if st['significant'] else 'dropped'}")
            continue
        if st.get("near_miss"):  # judged against the near miss, which is not what is carried
            print(f"near miss {st['of']}: refined to {st['label']}: held-out cost {st['held_out_cost_before']:.4g}"
                  f" -> {st['held_out_cost_after']:.4g} ({100 * st['reduction']:.1f}%, ΔBIC {st['delta_bic']:.0f}):"
                  f" {'kept' if st['significant'] else _not_kept(st)}")
            continue
        print(f"refining {st['of']} to {st['label']}: held-out cost {st['held_out_cost_before']:.4g} ->"
              f" {st['held_out_cost_after']:.4g} ({100 * st['reduction']:.1f}%, ΔBIC {st['delta_bic']:.0f}):"
              f" {'carried instead' if st['significant'] else _not_kept(st)}")
    for st in (d.continued or {}).get("steps", []):
        refined = f", {st['refined_from']} refined" if st.get("refined_from") else ""
        print(f"going on, {st['label']} (best of {len(st['screened'])} screened{refined}): held-out cost"
              f" {st['held_out_cost_before']:.4g} -> {st['held_out_cost_after']:.4g} ({100 * st['reduction']:.1f}%,"
              f" ΔBIC {st['delta_bic']:.0f}): {'kept' if st['significant'] else _not_kept(st) + ', the search ends'}")
    for line in remaining_lines(d.remaining):
        print(line)
    for line in carry_lines(d.carry, args):
        print(line)
    print(f"diagnosis took {d.wall_s:.1f} s")
    outputs = Outputs()  # after the results are printed: a failed write loses nothing
    if args.json:
        if library_warnings.counts():
            out["warning_counts"] = library_warnings.counts()
        outputs.write_text(args.json, json_text(out))
    if args.report:
        from online_id.plots.diagnosis import write_report

        outputs.write_folder(args.report, lambda tmp: write_report(d, tmp))
    if d.interrupted:
        print(f"interrupted ({termination.signal_name()}): the diagnosis above covers the {len(d.candidates)}"
              " candidate(s) fitted until then", file=sys.stderr)
        return outputs.status(termination.exit_status())
    return outputs.status()


def near_miss_lines(near_misses: list[dict]) -> list[str]:
    """What the refinements of each candidate the training data support (the held-out data not) came to."""
    return [f"  {m['of']}: not significant, but it lowers the training BIC: its refinements (below) "
            + (f"come to {m['label']}, {100 * m['reduction']:.1f}% below the base model on held-out data (ΔBIC"
               f" {m['delta_bic']:.0f}): {'a candidate of its own (above)' if m['significant'] else 'not significant'}"
               if m["label"] else "add nothing significant to it")
            for m in near_misses]


def reading_flags(args) -> list[str]:
    """How ``args`` read the log and which car it is (the READING_FLAGS the next steps of a verdict carry too;
    --vehicle unless the default), to repeat in a command printed for the same log."""
    from online_id.trust.consistency import READING_FLAGS

    out = []
    for flag in READING_FLAGS:
        value = getattr(args, flag[2:].replace("-", "_"), None)
        if value is not None and not (flag == "--vehicle" and value == "haro2008"):
            out += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return out


def carry_lines(carry: dict | None, args) -> list[str]:
    """How to carry the named effects into the estimate: the flags, and ``--effects-from`` with --json."""
    if not carry:
        return []
    log = shlex.join([str(args.log), *reading_flags(args)])
    lines = []
    if carry["online"]:
        lines.append(f"carry it online: online-id estimate {log} {carry['estimate_flags']}")
    if carry["not_online"]:
        lines.append(f"no filter form yet for {', '.join(carry['not_online'])}: the online filters cannot carry it;"
                     f" the batch fit can: online-id fit {log} {carry['fit_flags']}")
    elif carry["fit"]:
        lines.append(f"in the batch fit: online-id fit {log} {carry['fit_flags']}")
    if args.json:
        lines.append(f"or take them from this diagnosis: --effects-from {shlex.quote(str(args.json))}"
                     " (estimate, fit, listen, batch)")
    return lines


def remaining_lines(remaining: dict | None) -> list[str]:
    """The remaining gap (diagnosis step 8) as a table: per channel, the held-out misfit in noise σ, overall and by
    |a_y|, a_x and speed band (a dash where the held-out data have no block in the band)."""
    if not remaining:
        return []
    lines = [f"what {remaining['model']} still misses on held-out data, in noise σ of a"
             f" {remaining['block_samples']}-sample block (1: at the noise;"
             f" a_x: {remaining['longitudinal_acceleration']}):"]
    for c, e in remaining["channels"].items():
        def bands(key, e=e):
            return " ".join(f"{b['band']}:{'-' if b['sigma'] is None else format(b['sigma'], '.3g')}" for b in e[key])

        lines.append(f"  {c} (σ {e['noise_std']:.3g}): {e['sigma']:.3g} overall, mean {e['mean_sigma']:+.3g}")
        lines.append(f"    by |a_y| [m/s²] {bands('by_lateral_acceleration')}")
        lines.append(f"    by a_x           {bands('by_longitudinal_acceleration')}")
        lines.append(f"    by speed [m/s]   {bands('by_speed')}")
    return lines + kinematics_line(remaining.get("lateral_kinematics"))


def _not_kept(step: dict) -> str:
    """Why a step was not kept: not significant, or its effect fitted onto the edge of its range (diagnose.py
    ``_at_bound``: absent or unphysical there)."""
    bound = step.get("at_bound")
    return f"at its bound ({', '.join(bound)}): not kept" if bound else "not significant"
