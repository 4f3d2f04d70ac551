"""The descriptions of a function's parameters, from its numpydoc ``Parameters`` section.

A job's parameter is described once, in its workflow function's docstring; the command line's
help and the docs' parameter table read it from there when its ``Param`` says nothing itself
(``pipeline.steps.parameters.help_of``). The section is read here (some twenty lines) rather
than with numpydoc: numpydoc is a docs tool the product does not otherwise install, and the
command line needs only the ``Parameters`` section of docstrings the project writes itself.
"""

from __future__ import annotations

import inspect
import re

# a section's title, underlined with dashes ("Parameters" / "----------")
_UNDERLINE = re.compile(r"^-{3,}$")
# reStructuredText's inline markup: ``code``, `text` and :role:`text`
_MARKUP = re.compile(r"(?::[\w:]+:)?`{1,2}([^`]+)`{1,2}")


def parameter_descriptions(function) -> dict[str, str]:
    """Parameter name -> its description (one line, markup as written) in the numpydoc
    ``Parameters`` section of ``function``'s docstring; ``{}`` when it has none.

    An entry is ``name : type`` (or ``name``) at the section's indent, its description the
    indented lines below it; ``a, b : type`` describes both; ``*args, **params`` name ``args``
    and ``params``.
    """
    lines = inspect.cleandoc(inspect.getdoc(function) or "").splitlines()
    described: dict[str, str] = {}
    names: list[str] = []
    for line in _section(lines, "Parameters"):
        if not line.strip():
            continue
        if not line[0].isspace():  # an entry: "name : type"
            names = [n.strip().lstrip("*") for n in line.partition(" : ")[0].split(",")]
            described.update({n: "" for n in names})
        elif names:
            for n in names:
                described[n] = f"{described[n]} {line.strip()}".strip()
    return described


def _section(lines: list[str], title: str) -> list[str]:
    """The lines of section ``title`` (below its underline, up to the next section)."""
    for i in range(len(lines) - 1):
        if lines[i].strip() == title and _UNDERLINE.match(lines[i + 1].strip()):
            body = lines[i + 2:]
            end = next((j for j in range(len(body) - 1)
                        if body[j].strip() and not body[j][0].isspace()
                        and _UNDERLINE.match(body[j + 1].strip())), len(body))
            return body[:end]
    return []


def plain(description: str) -> str:
    """A description as a help text: its inline markup dropped (``code`` and
    :func:`name` as the text) and without the final full stop (the command line may add
    " (default X)")."""
    return _MARKUP.sub(r"\1", description).strip().removesuffix(".")
