"""The docs site builds with warnings as errors, its generated parts follow the code, and the README's
links resolve (issue 28).

``mkdocs build --strict`` fails on a broken link or anchor, a docstring griffe cannot read and a page
missing from the navigation. The docs extra (``.[docs]``) is installed by ``scripts/test.sh``; without it
the build tests skip, except under CI, where a skip would hide a broken site.
"""

from __future__ import annotations

import argparse
import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
README_MAX_LINES = 200
#: A Markdown link or image target: ``[text](target)``.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _docs_installed() -> bool:
    return all(importlib.util.find_spec(m) is not None for m in ("mkdocs", "material", "mkdocstrings_handlers"))


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built once for this module, strictly, into a temporary folder."""
    if not _docs_installed():
        if os.environ.get("CI"):
            pytest.fail("the docs extra is not installed (pip install '.[docs]'): the docs build cannot be checked")
        pytest.skip("the docs extra is not installed (pip install '.[docs]')")
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, f"mkdocs build --strict failed:\n{res.stdout}\n{res.stderr}"
    return out


def _page(site: Path, doc: str) -> str:
    """The HTML MkDocs made of ``docs/<doc>`` (``guide/csv-run.md`` -> ``guide/csv-run/index.html``)."""
    stem = doc.removesuffix(".md")
    return (site / ("index.html" if stem == "index" else f"{stem}/index.html")).read_text(encoding="utf-8")


def _parsers(parser: argparse.ArgumentParser):
    """Every parser under ``parser`` (sub-commands and theirs), itself first."""
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_the_site_builds_strictly(site):
    assert (site / "index.html").is_file()
    assert "online_id.workflows.estimate_job.estimate" in _page(site, "reference/api.md")  # mkdocstrings rendered it


def test_the_cli_reference_has_every_sub_command_and_every_flag(site):
    from online_id.cli.main import build_parser

    page = html.unescape(_page(site, "reference/cli.md"))
    missing = []
    for parser in _parsers(build_parser()):
        if parser.prog not in page:
            missing.append(parser.prog)
        for action in parser._actions:
            missing += [f"{parser.prog} {o}" for o in action.option_strings if o not in page]
            if action.help and action.help != argparse.SUPPRESS and action.option_strings[:1] != ["-h"]:
                first_words = " ".join(action.help.split()[:4])
                if "%(" not in first_words and first_words not in page:
                    missing.append(f"{parser.prog} {action.dest}: help {first_words!r}")
    assert not missing, f"not in the CLI reference: {missing}"


def test_the_effects_table_lists_every_registered_effect(site):
    from online_id.effects import EFFECTS

    page = html.unescape(_page(site, "guide/vehicles-and-effects.md"))
    assert "simulation / fit / online" in page
    for name, cls in EFFECTS.items():
        assert f"<code>{name}</code>" in page, name
        assert " ".join(cls.summary.split()[:4]) in page, name


#: The effects without a filter form (each says why).
NOT_ONLINE = ("steering_compliance", "accelerometer_lever_arm")


def test_the_effects_table_says_which_forms_each_effect_has_and_why_one_is_missing():
    """The table's last column comes from the effects themselves: an effect without a form gives its reason
    (issue 25: every effect has all three but steering compliance, which no run can see, and the accelerometer's
    lever arm, whose ṙ row moves with the estimated parameters: issue 38)."""
    sys.path.insert(0, str(ROOT / "scripts" / "docs"))
    try:
        from generated import effect_forms, render_effects
    finally:
        sys.path.pop(0)
    from online_id.effects import EFFECTS
    from online_id.vehicle import load_vehicle

    known = load_vehicle("haro2008").known
    forms = {n: effect_forms(cls.parse(cls.example), known) for n, cls in EFFECTS.items()}
    for name, f in forms.items():
        assert list(f) == ["simulation", "fit", "online"]
        assert not f["simulation"] and not f["fit"], (name, f)
        assert bool(f["online"]) == (name in NOT_ONLINE), (name, f)
    assert "exactly equivalent to the base model" in forms["steering_compliance"]["online"]
    assert "no filter form yet" in forms["accelerometer_lever_arm"]["online"]
    table = render_effects()
    assert "| yes / yes / no (online: no filter form: exactly equivalent" in table
    assert table.count("| yes / yes / yes |") == len(EFFECTS) - len(NOT_ONLINE)


def test_the_effects_table_says_what_each_filter_form_adds():
    """The last column is read from the effects' extra states: every state an effect adds to the filters is
    named with how it enters (a μ per axle for tire_saturation_axles, a lag for the delays), and the effect
    without a filter form has none."""
    sys.path.insert(0, str(ROOT / "scripts" / "docs"))
    try:
        from generated import render_effects
    finally:
        sys.path.pop(0)
    from online_id.effects import EFFECTS
    from online_id.vehicle import load_vehicle

    known = load_vehicle("haro2008").known
    table = render_effects()
    assert "`--effects-from DIAG.json`" in table.splitlines()[0]
    rows = {line.split("|")[1].split("`")[1]: line for line in table.splitlines()[2:]}
    assert set(rows) == set(EFFECTS)
    for name, cls in EFFECTS.items():
        online = rows[name].rstrip(" |").rsplit("|", 1)[1]
        effect = cls.parse(cls.example)
        if not effect.has_filter_form(known):
            assert online.strip() == "—", name
            continue
        assert f"`--effect {name}" in online, name
        for state in effect.filter_states(known):
            assert f"`{state.parameter}`" in online, (name, state.parameter)
    axles = rows["tire_saturation_axles"]
    assert "front axle's μ" in axles and "rear axle's μ" in axles and "refines `tire_saturation`" in axles
    assert "one μ for both axles" in rows["tire_saturation"]
    assert "read the channel τ̂ later" in rows["sensor_delay"]
    assert "read every channel and the speed τ̂ later" in rows["steering_delay"]


def test_the_site_loads_nothing_from_the_network(site):
    """No web fonts, CDN styles or scripts: the site reads offline (the theme's Google fonts are off)."""
    remote = re.compile(r"<(?:link|script|img)\b[^>]*\b(?:href|src)=\"(?:https?:)?//", re.I)
    pages = [p for p in site.rglob("*.html") if remote.search(p.read_text(encoding="utf-8"))]
    assert not pages, f"pages that load from the network: {pages}"


def _readme_links() -> list[str]:
    text = README.read_text(encoding="utf-8")
    return [t for t in LINK.findall(text) if not re.match(r"[a-z]+:", t)]  # local links, not http: or mailto:


def test_the_readme_is_short_and_starts_with_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES
    blocks = re.findall(r"```bash\n(.*?)\n```", text, re.S)
    assert blocks[0].strip() == "python3 -m venv .venv && .venv/bin/pip install -q . && .venv/bin/online-id estimate"
    assert blocks[1].strip() == "scripts/test.sh"


def test_the_readme_links_resolve_to_files():
    links = _readme_links()
    assert links, "the README links into the docs"
    broken = [t for t in links if not (ROOT / t.split("#")[0]).exists()]
    assert not broken, f"README links to missing files: {broken}"


def test_the_readme_links_into_the_docs_hit_their_anchors(site):
    broken = []
    for target in _readme_links():
        path, _, anchor = target.partition("#")
        if not (path.startswith("docs/") and path.endswith(".md") and anchor):
            continue
        if f'id="{anchor}"' not in _page(site, path.removeprefix("docs/")):
            broken.append(target)
    assert not broken, f"README links to missing anchors: {broken}"
