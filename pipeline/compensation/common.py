"""Helpers shared by the controller writers: options, units, headers, axis numbering, and the
tables of a rotary axis measured over one whole turn."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2, "A": 3, "B": 4, "C": 5}
TURN_DEG = 360.0
_TOLERANCE = 1e-6  # [mm, deg] positions closer than this are one position


@dataclass(frozen=True)
class Options:
    spacing_mm: float | None = None      # table spacing of equidistant formats
    reference_mm: float | None = None    # where a table is 0 (reference point), default: see below
    fanuc_unit_um: float = 1.0           # Fanuc detection unit [um] (rotary: [0.001 deg])
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


def full_turn(profile) -> bool:
    """Whether the profile is of a rotary axis whose targets cover one whole turn: the first and
    last target 360 deg apart, or less apart with the step that closes the turn (last target to
    first + 360 deg) no longer than the longest step between targets.

    A table over such an axis runs from a start position to start + 360 deg with the same value
    at both ends (``turn_grid``, ``resample_turn``).
    """
    import numpy as np

    from features.readings import schema

    target = np.asarray(profile.target, float)
    if not schema.is_rotary(profile.axis) or len(target) < 2:
        return False
    closing = TURN_DEG - (target[-1] - target[0])
    return (abs(closing) < _TOLERANCE
            or 0 < closing <= float(np.max(np.diff(target))) + _TOLERANCE)


def turn_grid(target, spacing_deg: float | None, max_points: int) -> np.ndarray:
    """Equidistant points over one turn [deg], start to start + 360 deg, with a step that divides
    360 deg: the targets' own step when they are equidistant, else a quarter of the smallest
    target interval rounded down to 1, 2, 2.5 or 5 x 10^k (``profile.nice_step``); a given
    ``spacing_deg`` is shortened to 360 / ceil(360 / spacing). The start is the first target
    when the targets lie on the points, else the multiple of the step below it.

    Raises
    ------
    InputError
        A spacing not > 0 or more than ``max_points`` points (``parameter="spacing"``).
    """
    import numpy as np

    from features.readings.errors import InputError
    from pipeline.compensation.profile import nice_step

    target = np.asarray(target, float)
    steps = np.diff(target)
    even = bool(np.allclose(steps, steps[0], rtol=0, atol=1e-9))
    if spacing_deg is None:
        spacing_deg = float(steps[0]) if even else nice_step(float(np.min(steps)) / 4)
    if not spacing_deg > 0:
        raise InputError("must be > 0", parameter="spacing")
    n = int(np.ceil(TURN_DEG / spacing_deg - 1e-9))
    if n + 1 > max_points:
        raise InputError(f"{n + 1} points at {TURN_DEG / n:g} deg spacing; this controller takes "
                         f"at most {max_points}: choose a larger spacing", parameter="spacing")
    step = TURN_DEG / n
    on_points = even and abs(steps[0] - step) < 1e-9
    start = float(target[0]) if on_points else np.floor(target[0] / step + 1e-9) * step
    return start + step * np.arange(n + 1)


def resample_turn(target, values, points) -> tuple[np.ndarray, float]:
    """Values at ``points`` (one turn, ``turn_grid``) by linear interpolation around the turn:
    positions taken modulo 360 deg, targets one turn apart (0 and 360 deg) averaged, the closing
    step interpolated from the last target to the first; the last point gets the first point's
    value. Returns the table and the interpolation error at the measured targets [value unit]:
    max |table interpolated back - measured|."""
    import numpy as np

    target, values = np.asarray(target, float), np.asarray(values, float)
    where = np.round(np.mod(target, TURN_DEG), 9) % TURN_DEG
    unique, index = np.unique(where, return_inverse=True)
    merged = np.bincount(index, values) / np.bincount(index)
    table = np.interp(points, unique, merged, period=TURN_DEG)
    table[-1] = table[0]
    back = np.interp(target, points, table, period=TURN_DEG)
    return table, float(np.max(np.abs(back - values)))


def closed_turn(profile) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The targets [deg] and the mean deviations moving + and - [arcsec] of a full-turn profile
    with the turn closed: when the last target is short of first + 360 deg, that position is
    added with the first target's deviations. Other profiles are returned as they are."""
    import numpy as np

    target, up, down = profile.target, profile.mean_up, profile.mean_down
    if not full_turn(profile) or target[-1] - target[0] > TURN_DEG - _TOLERANCE:
        return target, up, down
    return (np.r_[target, target[0] + TURN_DEG], np.r_[up, up[0]], np.r_[down, down[0]])


def direction_dependent(profile) -> bool:
    """Whether the profile's reversal value varies along the axis by more than its uncertainty
    (``AxisProfile.reversal_variation``): then a format that has a table per approach direction
    gets both tables, and one whose reversal does not vary keeps its one-table form."""
    return bool(profile.reversal_variation()["direction_dependent"])


def table_points(profile, spacing: float | None, max_points: int) -> tuple[np.ndarray, bool]:
    """The points [mm, deg] of an equidistant table and whether they are one turn (a full-turn
    rotary axis, ``full_turn``: ``turn_grid``; else ``profile.grid`` over the targets)."""
    from pipeline.compensation.profile import grid

    if full_turn(profile):
        return turn_grid(profile.target, spacing, max_points), True
    return grid(profile.target, spacing, max_points), False


def resampled(profile, values, points, turn: bool) -> tuple[np.ndarray, float]:
    """``values`` per target [um, arcsec] at the table ``points`` and the interpolation error at
    the measured targets: around the turn (``resample_turn``) or along the axis
    (``profile.resample``)."""
    from pipeline.compensation.profile import resample

    return (resample_turn if turn else resample)(profile.target, values, points)


def error_table(profile, spacing: float | None, max_points: int):
    """The bidirectional mean error of an equidistant one-table format: points [mm, deg], the
    error there [um, arcsec], the interpolation error at the measured targets [um, arcsec] and
    whether the table is one turn (``table_points``, ``resampled``)."""
    points, turn = table_points(profile, spacing, max_points)
    return (points, *resampled(profile, profile.position_error, points, turn), turn)
