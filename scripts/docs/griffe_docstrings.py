"""Griffe extension for the API reference: reads the project's docstrings as they are written.

The code's docstrings follow two conventions that mkdocstrings does not take as they are:

* Sphinx cross-reference roles (``:class:`Fit```, ``:meth:`~online_id.x.y```): shown as code,
  the last component only when the target starts with ``~`` (as Sphinx shows it);
* reStructuredText literal blocks introduced by a paragraph ending in ``::``: the ``::`` becomes ``:``
  (the indented block after the blank line is a code block in Markdown as it is);
* numpy-style sections whose entries are ``name : what it is [unit]`` (the type lives in the
  signature, the text after the colon is the description): each entry becomes ``name`` with the
  text indented under it, so the description lands in the description column, not in the type.

Only the docstring text given to the renderer changes; the code is not touched. Loaded by
``mkdocs.yml`` (``extensions:`` of the python handler).

The folders ``drivers/`` and ``replay/`` install as ``online_id.drivers`` and ``online_id.replay``
(``package-dir`` in ``pyproject.toml``), which griffe, reading the source tree, does not know: once it has
loaded ``online_id`` they are loaded from their folders and set as its members, so the reference names them
as a user imports them.
"""

from __future__ import annotations

import re

from griffe import Extension

#: Top-level folders of the repository that install inside ``online_id`` (pyproject.toml's package-dir).
INSTALLED_INSIDE = ("drivers", "replay")

#: ``:role:`target``` with an optional ``~`` (show the last component only).
ROLE = re.compile(r":(?:py:)?(?:class|meth|func|data|attr|mod|exc|obj|const|ref):`(~?)([^`]+)`")
#: A paragraph's closing ``::`` (a reStructuredText literal block follows): ``text::`` reads ``text:``, and a
#: ``::`` after a space is dropped, as Sphinx shows them.
LITERAL_AFTER_TEXT = re.compile(r"(?<=\S)::$", re.M)
LITERAL_ALONE = re.compile(r"[ \t]+::$", re.M)
#: The numpy section headers used in the code.
SECTIONS = ("Parameters", "Attributes", "Other Parameters", "Returns", "Yields", "Raises")
#: ``name : description`` (or ``a, b : description``) at the start of a section entry.
ENTRY = re.compile(r"^(?P<indent>\s*)(?P<names>[A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s+:\s+(?P<text>.*)$")


def _role(match: re.Match) -> str:
    short, target = match.group(1), match.group(2)
    return f"`{target.rsplit('.', 1)[-1] if short else target}`"


def convert(text: str) -> str:
    """The docstring with roles as code spans and ``name : description`` entries as numpy ones."""
    text = ROLE.sub(_role, text)
    text = LITERAL_ALONE.sub("", LITERAL_AFTER_TEXT.sub(":", text))
    lines, out = text.split("\n"), []
    section_indent = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        nxt = lines[i + 1].strip() if i + 1 < len(lines) else ""
        if stripped and nxt and set(nxt) == {"-"}:  # a section header: entries follow only in SECTIONS
            section_indent = len(line) - len(line.lstrip()) if stripped in SECTIONS else None
            out.append(line)
            continue
        if section_indent is not None and stripped and not set(stripped) == {"-"}:
            indent = len(line) - len(line.lstrip())
            if indent < section_indent:
                section_indent = None
            elif indent == section_indent:
                m = ENTRY.match(line)
                if m:
                    out += [f"{m['indent']}{m['names']}", f"{m['indent']}    {m['text']}"]
                    continue
        out.append(line)
    return "\n".join(out)


class ProjectDocstrings(Extension):
    """Rewrites each object's docstring text with :func:`convert` as griffe loads it."""

    def on_instance(self, *, obj, **kwargs) -> None:  # noqa: ARG002 (griffe passes more keywords)
        if obj.docstring is not None:
            obj.docstring.value = convert(obj.docstring.value)

    def on_package(self, *, pkg, loader, **kwargs) -> None:  # noqa: ARG002
        if pkg.name == "online_id":
            for name in INSTALLED_INSIDE:
                pkg.set_member(name, loader.load(name))  # its path becomes online_id.<name>
