"""MkDocs hook: the parts of the docs that are rendered from the code at build time.

A page line ``<!-- online-id cli reference -->`` becomes every sub-command of
``online_id.cli.main.build_parser()`` (nested ones such as ``plot convergence`` included): its one-line
help, usage, description and each argument with its help text, defaults expanded as ``--help`` shows
them. A line ``<!-- online-id effects table -->`` becomes a table of the effects registry
(``online_id.effects.EFFECTS``): name, value syntax, summary, channels, its three forms (simulation,
fit, online), with the reason where one is missing, and what its filter form adds to the online filters
(``estimate|listen|batch --effect``, ``--effects-from DIAG.json``), read from its extra states. Nothing is copied by
hand, so the pages follow the flags and the registry as they change. Loaded by ``mkdocs.yml``
(``hooks:``); ``tests/test_docs.py`` checks the built pages against the parsers and the registry.
"""

from __future__ import annotations

import argparse
import html
import re

CLI_MARKER = "<!-- online-id cli reference -->"
EFFECTS_MARKER = "<!-- online-id effects table -->"
#: Width of the usage lines (argparse wraps them; a fixed width keeps the page the same on every machine).
USAGE_WIDTH = 100


def _formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.HelpFormatter(prog, width=USAGE_WIDTH, max_help_position=40)


def _sub_commands(parser: argparse.ArgumentParser):
    """(name, one-line help, parser) of each sub-command, in the order they were added."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name) or "", sub


def _text(text: str) -> str:
    """Help text as literal Markdown: HTML special characters (``<log>``) and emphasis markers escaped."""
    return html.escape(text, quote=False).replace("*", "\\*")


def _cell(text: str) -> str:
    """Text for a Markdown table cell: one line, pipes escaped too."""
    return _text(" ".join(text.split())).replace("|", "\\|")


def _options_table(parser: argparse.ArgumentParser) -> list[str]:
    fmt = _formatter(parser.prog)
    lines: list[str] = []
    for group in parser._action_groups:
        rows = []
        for action in group._group_actions:
            if action.help == argparse.SUPPRESS or isinstance(action, (argparse._SubParsersAction,
                                                                        argparse._HelpAction)):
                continue
            invocation = fmt._format_action_invocation(action)
            help_text = fmt._expand_help(action) if action.help else ""
            if action.required and action.option_strings:
                help_text = f"(required) {help_text}"
            rows.append(f"| `{invocation}` | {_cell(help_text)} |")
        if rows:
            lines += ["", f"*{group.title}*", "", "| argument | meaning |", "| --- | --- |", *rows]
    return lines


def _command(name: str, one_line: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    parser.formatter_class = _formatter
    lines = ["", f"{'#' * level} `{parser.prog}`", ""]
    if one_line:
        lines += [f"{one_line[0].upper()}{one_line[1:]}.", ""]
    lines += ["```text", parser.format_usage().strip(), "```"]
    if parser.description:
        lines += ["", _text(parser.description)]
    lines += _options_table(parser)
    for sub_name, sub_help, sub in _sub_commands(parser):
        lines += _command(sub_name, sub_help, sub, level + 1)
    return lines


def render_cli() -> str:
    """The reference as Markdown: the command list, then a section per sub-command."""
    from online_id.cli.main import build_parser

    parser = build_parser()
    parser.formatter_class = _formatter
    commands = list(_sub_commands(parser))
    lines = ["```text", parser.format_usage().strip(), "```", "", _text(parser.description or ""), "",
             "| command | what it does |", "| --- | --- |"]
    lines += [f"| [`online-id {n}`](#{_anchor(sub.prog)}) | {_cell(h)} |" for n, h, sub in commands]
    lines += _options_table(parser)
    for name, one_line, sub in commands:
        lines += _command(name, one_line, sub, level=2)
    return "\n".join(lines) + "\n"


def _anchor(prog: str) -> str:
    """The id MkDocs' toc extension gives the heading `` `prog` ``."""
    return re.sub(r"[^\w\- ]", "", prog).strip().lower().replace(" ", "-")


def render_effects() -> str:
    """The effects registry as a Markdown table; each form is asked of the effect's example value on the
    built-in ``haro2008`` (:func:`effect_forms`)."""
    from online_id.effects import EFFECTS
    from online_id.vehicle import load_vehicle

    known = load_vehicle("haro2008").known
    lines = ["| effect | `simulate --effect NAME=VALUE` | what it adds | channels | simulation / fit / online"
             " | in the filters: `--effect`, `--effects-from DIAG.json` |",
             "| --- | --- | --- | --- | --- | --- |"]
    for name, cls in EFFECTS.items():
        effect = cls.parse(cls.example)
        forms = effect_forms(effect, known)
        cell = " / ".join("no" if missing else "yes" for missing in forms.values())
        why = "; ".join(f"{form}: {reason}" for form, reason in forms.items() if reason)
        channels = ", ".join(f"`{c}`" for c in cls.channels) or "—"
        refines = f" (refines `{cls.refines}`: `diagnose` tries it when named)" if cls.refines else ""
        lines.append(f"| `{name}`{refines} | {_cell(cls.syntax)} | {_cell(cls.summary)} | {channels} |"
                     f" {cell}{' (' + _cell(why) + ')' if why else ''} |"
                     f" {filter_form(effect, known) if not forms['online'] else '—'} |")
    return "\n".join(lines) + "\n"


def filter_form(effect, known) -> str:
    """What ``--effect NAME`` (or ``--effects-from``) adds to the online filters, read from the effect's extra
    states (:class:`online_id.effects.base.ExtraState`): the flag, then each state, how it enters the model and
    its prior σ (per channel where the channels differ). Markdown for one table cell."""
    import numpy as np

    from online_id.model.lateral import OUTPUT_NAMES, STATE_NAMES

    cls = type(effect)
    axle_names = {(0,): "the front axle's μ", (1,): "the rear axle's μ", (0, 1): "one μ for both axles"}
    by_channel = {c: cls.to_estimate(c).filter_states(known) for c in cls.channels} or {"": effect.filter_states(known)}
    parts = []
    for k, s in enumerate(effect.filter_states(known)):
        if s.tyre_axles:
            how = f"{axle_names.get(tuple(s.tyre_axles), 'μ')} in the tanh tyre law of the prediction"
        elif s.lags:
            lagged = [c for c in s.lags if c != "speed"]
            read = ("every channel" if lagged == list(OUTPUT_NAMES)
                    else "the channel" if tuple(s.lags) == (effect.channel,) else ", ".join(lagged))
            how = f"a lag: the filters read {read}{' and the speed' if 'speed' in s.lags else ''} τ̂ later"
        elif s.output_state is not None:
            coupling = np.asarray(s.output_state)
            how = "; ".join(f"{OUTPUT_NAMES[i]} += {s.parameter}·{coupling[i, j]:.3g}·{STATE_NAMES[j]}"
                            for i, j in zip(*np.nonzero(coupling)))
        elif s.steering or any(s.output):
            how = "added to the channel (at the steering wheel: δ = (δH − e)/i_s)" if cls.channels else "an offset"
        else:
            how = "an extra state"
        priors = {c: (states[k].prior_std, "" if states[k].unit in ("-", "") else f" {states[k].unit}")
                  for c, states in by_channel.items()}
        if len(set(priors.values())) == 1:
            prior = "prior σ {:.3g}{}".format(*next(iter(priors.values())))
        else:
            prior = "prior σ " + ", ".join(f"{v:.3g}{u} ({c})" for c, (v, u) in priors.items())
        parts.append(f"`{s.parameter}`: {_cell(how)}, {_cell(prior)}")
    starts = ":".join(p.name.upper() for p in cls.fit_parameters())
    return f"`--effect {cls.name}{':CHANNEL' if cls.channels else ''}[:{starts}]`: " + "; ".join(parts)


def effect_forms(effect, known) -> dict[str, str]:
    """Which of its three forms an effect has: ``{"simulation": "", "fit": "", "online": ""}`` with the reason
    an effect gives (its OnlineIdError, without its name) where a form is missing. Simulation: every effect
    (the stage hooks); fit: the block-mean form the fits and the diagnosis use; online: the filter form
    (``estimate``, ``listen``, ``batch --effect``)."""
    import numpy as np

    from online_id.effects.base import BlockContext
    from online_id.errors import OnlineIdError

    def reason(call) -> str:
        try:
            call()
        except OnlineIdError as exc:
            text = str(exc)
            return text.split(": ", 1)[1] if text.startswith(effect.label) else text
        return ""

    from online_id.model.lateral import OUTPUT_NAMES

    time = np.arange(4) * 0.01 + 0.005
    shape = (4, len(OUTPUT_NAMES))
    context = BlockContext(time=time, block_dt=0.01, unit_steering_response=lambda: np.zeros(shape),
                           speed=np.full(4, 20.0))
    return {"simulation": "",
            "fit": reason(lambda: effect.block_means(np.zeros(shape), context)),
            "online": reason(lambda: effect.filter_states(known))}


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' hook signature)
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, render_cli())
    if EFFECTS_MARKER in markdown:
        markdown = markdown.replace(EFFECTS_MARKER, render_effects())
    return markdown
