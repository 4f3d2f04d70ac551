"""Names of the readings table (docs/data-contract.md §1): public, never rename.

After ``features.readings.read_readings`` a frame always has every column in ``REQUIRED``
plus ``visit`` and ``repeat`` (defaults filled in) and ``deviation_um`` (computed from
``measured`` when absent), with these normalised values:

- ``method`` is ``"linear"`` or ``"pendulum"``; ``direction`` is ``"+"`` or ``"-"``;
- ``machine_id``, ``axis``, ``test_id``, ``visit`` are str; ``cycle`` and ``repeat`` int;
- ``deviation_um`` is in um for linear axes (X, Y, Z) and arcsec for rotary axes (A, B, C);
- optional columns appear only when the input had them.
"""

from __future__ import annotations

from features.readings import layouts


def __getattr__(name: str):
    """``FORMATS`` (the input layouts a readings file may have: the ``--format`` choices) and
    ``DATA_HELP`` (the help text of every readings argument), read from the records of
    ``features.readings.layouts`` when asked for, so that a registered layout counts."""
    if name in ("FORMATS", "DATA_HELP"):
        return getattr(layouts, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


REQUIRED = ("machine_id", "axis", "test_id", "method", "target", "direction", "cycle")
DEVIATION = "deviation_um"
MEASURED = "measured"
OPTIONAL = (
    "visit", "repeat", "started_at", "measured_at", "feed_mm_min", "dwell_s",
    "machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct", "operating_hours",
)
NUMERIC_OPTIONAL = (
    "feed_mm_min", "dwell_s", "machine_temp_c", "ambient_temp_c", "pressure_hpa",
    "humidity_pct", "operating_hours",
)
DATETIME_OPTIONAL = ("started_at", "measured_at")
CONDITIONS = ("feed_mm_min", "dwell_s", "machine_temp_c", "ambient_temp_c", "pressure_hpa",
              "humidity_pct")

# A machine axis: what a fleet's series, models and views are kept per.
AXIS_KEYS = ("machine_id", "axis")
# A test: one run with one method, one feed, one set of conditions.
TEST_KEYS = ("machine_id", "axis", "visit", "test_id")
# A linear and a pendulum test are paired when they share these (docs/data-contract.md).
PAIR_KEYS = ("machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat")

METHODS = ("linear", "pendulum")
DIRECTIONS = ("+", "-")
LINEAR_AXES = ("X", "Y", "Z")
ROTARY_AXES = ("A", "B", "C")

DIRECTION_ALIASES = {
    "+": "+", "fwd": "+", "up": "+", "1": "+", "+1": "+", "1.0": "+", "+1.0": "+",
    "-": "-", "bwd": "-", "down": "-", "-1": "-", "-1.0": "-",
}
METHOD_ALIASES = {"linear": "linear", "lin": "linear", "pendulum": "pendulum", "pend": "pendulum"}

# The verdict that no physical effect is missing (docs/data-contract.md, section 4). The effect
# names themselves are the keys of models.physics.effects.EFFECTS (``EFFECT_NAMES`` there):
# one record per effect, so this layer, below the models, keeps no copy of the list.
NO_EFFECT = "none"


def is_rotary(axis: str) -> bool:
    return str(axis).upper() in ROTARY_AXES


def deviation_unit(axis: str) -> str:
    """Unit of ``deviation_um`` and of every ISO figure for this axis."""
    return "arcsec" if is_rotary(axis) else "um"


def unit_of(axes) -> str:
    """The deviation unit of every axis named in ``axes``: "um", "arcsec", or "um or arcsec"
    when linear and rotary axes are mixed (a label, for messages and table headings)."""
    units = sorted({deviation_unit(a) for a in set(axes)}, reverse=True)
    return " or ".join(units) if units else "um"


def position_unit(axis: str) -> str:
    return "deg" if is_rotary(axis) else "mm"


def deviation_scale(axis: str) -> float:
    """Factor from position units to deviation units: mm -> um or deg -> arcsec."""
    return 3600.0 if is_rotary(axis) else 1000.0


# ``frame.attrs[UNSTATED]``: the name columns a reader filled in because its file does not state
# them (an ecmc file names no axis; its machine is the file's name). ``--machine``/``--axis``
# then name them instead of selecting tests (``features.readings.selection``); with neither, a
# note says which name was taken.
UNSTATED = "unstated"
# ``frame.attrs[NAMED_BY]``: column -> where a reader read an unstated name from, when it read it
# from a naming convention rather than a field (an ecmc axis from its set-point PV's name,
# ``TGT_SET_PV=TARGET_DU:Z-PosCmd``): no note then, and ``--axis`` still renames it.
NAMED_BY = "named_by"
