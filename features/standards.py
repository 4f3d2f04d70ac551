"""The positioning-test standards the backlash paper names, one record each.

[BacklashNN] (section 2) lists ISO 230-2, ASME B5.54, JIS B6336 and the VDI/DGQ 3441:1982
recommendations as the procedures that define a bidirectional positioning test. They share the
test (a laser interferometer, repeated bidirectional approaches to a set of targets) but each
evaluates its own figures. A standard is supported only where its definitions could be
confirmed from public material; the others are listed with the reason, so that asking for one
is a clear refusal rather than figures computed after a guess.

References
----------
ISO 230-2:2014, clause 2 (the definitions in ``features.iso230``).
AMT, "ISO 230-2:2006 published", amtonline.org article 133530: ISO 230-2 "supersedes and
replaces" the NMTBA definitions and VDI/DGQ 3441.
JIS B 0182 (vocabulary), term 346, as quoted at kk.jisw.com/00530/post_469.html.
"""

from __future__ import annotations

from dataclasses import dataclass

from features.readings.errors import InputError


@dataclass(frozen=True)
class Standard:
    """One standard: its option name, title, whether the product evaluates it and why not.

    Attributes
    ----------
    name : str
        The value of ``--standard`` and of the ``standard`` parameter.
    title : str
        The standard as a report names it.
    supported : bool
        Whether its figures are computed.
    figures : tuple of str
        The axis figures it reports (the figures table's columns), when supported.
    reason : str
        Why it is not supported (empty when it is).
    """

    name: str
    title: str
    supported: bool
    figures: tuple[str, ...] = ()
    reason: str = ""


ISO230_2 = Standard("iso230-2", "ISO 230-2:2014", True,
                    figures=("A", "A_up", "A_down", "E", "E_up", "E_down", "M", "R", "R_up",
                             "R_down", "B", "B_mean"))
STANDARDS = (
    ISO230_2,
    Standard("vdi3441", "VDI/DGQ 3441:1982", False, reason=(
        "its figures (positional uncertainty P, deviation Pa, scatter Ps, reversal span U) "
        "are named in public material but their equations could not be confirmed; the "
        "guideline is withdrawn, replaced by ISO 230-2")),
    Standard("asme-b5.54", "ASME B5.54", False, reason=(
        "the standard is not public and no public source gives its positioning equations")),
    Standard("jis-b6336", "JIS B 6336", False, reason=(
        "the standard is not public; public material gives only one of its terms (the "
        "bidirectional repeatability at a target, JIS B 0182 term 346), not its evaluation")),
)
NAMES = tuple(s.name for s in STANDARDS)
DEFAULT = "iso230-2"


def standard(name: str) -> Standard:
    """The record of a supported standard.

    Raises
    ------
    InputError
        ``name`` is not a standard of ``STANDARDS``, or one that is not supported (the error
        gives the reason); ``.parameter`` is ``"standard"``.
    """
    found = {s.name: s for s in STANDARDS}.get(name)
    if found is None:
        raise InputError(f"unknown standard {name!r}; expected one of {', '.join(NAMES)}",
                         parameter="standard")
    if not found.supported:
        raise InputError(f"{found.title} is not supported: {found.reason}", parameter="standard")
    return found


def help_text() -> str:
    """The ``--standard`` help: every record, the unsupported ones marked."""
    listed = ", ".join(s.name if s.supported else f"{s.name} (not supported)" for s in STANDARDS)
    return f"standard whose figures to compute: {listed} (default {DEFAULT})"


def standards_table() -> str:
    """The docs' table of standards (``docs/iso.md`` holds it verbatim; a test compares)."""
    rows = ["| `--standard` | standard | supported | figures or reason |", "|---|---|---|---|"]
    for s in STANDARDS:
        detail = ", ".join(s.figures) if s.supported else s.reason
        rows.append(f"| `{s.name}` | {s.title} | {'yes' if s.supported else 'no'} | {detail} |")
    return "\n".join(rows)
