"""Helpers shared by the controller writers: options, units, headers, axis numbering."""

from __future__ import annotations

from dataclasses import dataclass

AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2, "A": 3, "B": 4, "C": 5}


@dataclass(frozen=True)
class Options:
    spacing_mm: float | None = None      # table spacing of equidistant formats
    reference_mm: float | None = None    # where a table is 0 (reference point), default: see below
    fanuc_unit_um: float = 1.0           # Fanuc detection unit
    sign: str | None = None              # "error" | "correction": table sign; None: documented


def table_sign(documented: str, options: Options) -> tuple[float, str]:
    """Factor turning values in the ``documented`` convention into the convention the site
    asked for (``options.sign``), and that convention's name: -1 when they differ (an error
    table written as corrections, or the reverse), else +1."""
    wanted = options.sign or documented
    return (1.0 if wanted == documented else -1.0), wanted


def reference_position(points, reference_mm: float | None) -> float:
    """The table point taken as the reference point (compensation 0 there): the one nearest
    ``reference_mm``, by default nearest 0 (machine zero) within the table, else its start."""
    import numpy as np

    wanted = 0.0 if reference_mm is None else reference_mm
    return float(points[int(np.argmin(np.abs(points - wanted)))])


def header(profile, controller: str, comment: str, lines: list[str]) -> str:
    """Comment block naming the machine, axis, source, signs and unconfirmed conventions."""
    head = [f"backlash-pipeline compensation for {controller}",
            f"machine {profile.machine_id}, axis {profile.axis}, from {profile.source} data",
            *lines, *profile.notes]
    return "".join(f"{comment} {line}\n" for line in head)


def units(profile) -> tuple[str, str]:
    """(position unit, deviation unit) of the profile's axis: ("mm", "um") for a linear axis,
    ("deg", "arcsec") for a rotary one (``features.readings.schema.ROTARY_AXES``)."""
    from features.readings import schema

    return schema.position_unit(profile.axis), schema.deviation_unit(profile.axis)


def in_units(name: str, profile) -> str:
    """A column name in the profile's axis's units: ``_mm`` -> ``_deg`` and ``_um`` ->
    ``_arcsec`` for a rotary axis, unchanged for a linear one."""
    position, error = units(profile)
    return "_".join(position if p == "mm" else error if p == "um" else p
                    for p in name.split("_"))
