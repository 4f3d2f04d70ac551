"""Circular tests (ISO 230-4): the contract of a ballbar file, its reader and the standard's
figures, the circular deviation G and the circular hysteresis H.

A circular test moves two axes of a plane round a circle of nominal radius R at a feed F,
once clockwise and once counter-clockwise; a telescopic ballbar between the spindle and a pivot
on the table records the radial deviation (measured minus nominal) at each angle. The table is
the data contract's section 11: one row per reading, the angle measured from the plane's first axis
(XY: from +X towards +Y). CCW is the direction of increasing angle.

Only that table (CSV or Parquet) is read. A ballbar vendor's own export (Renishaw's ``.b5r``
files, or the text its software exports) has no layout published that could be checked, so
none is guessed: such a file is refused by the contract's header check.

References
----------
ISO 230-4:2022, Test code for machine tools -- Part 4: Circular tests for numerically
controlled machine tools.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.readings.errors import InputError

# The plane's two axes; the first is along 0 deg, the second along 90 deg.
PLANES = {"XY": ("X", "Y"), "YZ": ("Y", "Z"), "ZX": ("Z", "X")}
DIRECTIONS = ("CW", "CCW")
DIRECTION_ALIASES = {"cw": "CW", "clockwise": "CW", "ccw": "CCW", "counterclockwise": "CCW",
                     "counter-clockwise": "CCW", "anticlockwise": "CCW",
                     "anti-clockwise": "CCW"}
REQUIRED = ("test_id", "machine_id", "plane", "direction", "angle_deg", "radius_mm",
            "feed_mm_min", "deviation_um")
OPTIONAL = ("visit", "started_at", "operating_hours")
# One circle: both directions of one machine, plane, visit, radius and feed.
CIRCLE_KEYS = ("machine_id", "plane", "visit", "radius_mm", "feed_mm_min")
# Fewer readings than this cannot show a 2-per-revolution ellipse beside a step.
MIN_READINGS = 16
# A ballbar's measuring range is about +-1 mm; beyond it deviation_um is not in um.
MAX_DEVIATION_UM = 1000.0
# The largest gap between readings of one run [deg]: beyond it the centre is not defined.
MAX_GAP_DEG = 180.0
# A ballbar reads to 0.1 um: a run whose deviations span less holds no measured path in um
# (deviation_um in mm: every value 1000 times too small).
RESOLUTION_UM = 0.1
# A machine tool's circular test spans more than this [um] (its path and the pivot's set-up
# offset); a run spanning less is noted: its column may be in mm.
PLAUSIBLE_SPAN_UM = 1.0


@dataclass(frozen=True)
class Run:
    """One direction of a circular test, its readings sorted by angle.

    Attributes
    ----------
    test_id, direction : str
        The run and its direction (CW or CCW).
    angle_deg, deviation_um : ndarray
        Angle from the plane's first axis [deg], radial deviation [um], sorted by angle.
    travel_deg : ndarray, optional
        Travel [deg] of each reading since the run's first in the order of the file (the
        order of capture), aligned with ``angle_deg``: the run's clock for its drift
        (``travel_deg``).
    """

    test_id: str
    direction: str
    angle_deg: np.ndarray
    deviation_um: np.ndarray
    travel_deg: np.ndarray | None = None

    def fit_run(self) -> tuple:
        """(direction, angle_deg, deviation_um, travel_deg): a run as ``models.machine.circle``'s
        fits take it."""
        return (self.direction, self.angle_deg, self.deviation_um, self.travel_deg)


@dataclass(frozen=True)
class Circle:
    """A circular test: one machine, plane, visit, radius and feed, one run per direction.

    Attributes
    ----------
    machine_id, plane, visit : str
    radius_mm : float
        Nominal radius R [mm].
    feed_mm_min : float
        Feed F [mm/min].
    runs : dict of str to Run
        By direction; a test may hold only one of the two.
    """

    machine_id: str
    plane: str
    visit: str
    radius_mm: float
    feed_mm_min: float
    runs: dict

    @property
    def axes(self) -> tuple[str, str]:
        return PLANES[self.plane]


# --------------------------------------------------------------------------- reading
def travel_deg(direction: str, theta_deg: np.ndarray) -> np.ndarray:
    """Travel [deg] of each reading since the run's first one, the readings in the order of
    capture: the run's clock for its drift (``models.machine.circle``). Readings sorted by angle instead
    give a ramp from the smallest angle: a column the fit does not need, never a bias."""
    s = 1.0 if direction == "CCW" else -1.0
    theta = np.asarray(theta_deg, float)
    return np.mod(s * (theta - theta[0]), 360.0) if len(theta) else theta




def read_circles(data, parameter: str = "data") -> pd.DataFrame:
    """Read and check a circular-test table (data contract section 11).

    Parameters
    ----------
    data : str, path-like or DataFrame
        A CSV or Parquet file, or a frame with the contract's columns.
    parameter : str
        The caller's parameter that passed ``data`` (named in errors about a frame).

    Returns
    -------
    DataFrame
        The contract's columns (labels as text, numbers as float, ``visit`` ``"1"`` where
        absent, ``started_at`` as UTC date-times), one row per reading.

    Raises
    ------
    InputError
        A missing column, a value that is not what the contract expects, a run too short or
        with too large a gap; naming the file, row and column.
    """
    from features.readings.io import read_table_rows

    if isinstance(data, pd.DataFrame):
        # positions inside, the caller's index labels in messages (a frame sliced from another)
        frame, file, rows = data.reset_index(drop=True), None, pd.Series(data.index)
        if frame.empty:
            raise InputError("no readings: the frame is empty", parameter=parameter)
    else:
        frame, file, rows = read_table_rows(data)
    return _checked(frame, file, rows)


def _checked(frame: pd.DataFrame, file, rows) -> pd.DataFrame:
    """The contract's columns typed and checked, or the first problem as an InputError."""
    from features.readings.validation import row_of, to_datetime, to_float, to_label

    known = {c.lower(): c for c in (*REQUIRED, *OPTIONAL)}
    frame = frame.rename(columns={c: known[str(c).lower()] for c in frame.columns
                                  if str(c).lower() in known})
    missing = [c for c in REQUIRED if c not in frame]
    if missing:
        raise InputError(f"missing required column {missing[0]!r} of a circular test "
                         f"(required: {', '.join(REQUIRED)}; a ballbar vendor's own export is "
                         "not read: convert it to this table)", file=file, row=1,
                         column=missing[0])
    out = pd.DataFrame({c: to_label(frame[c], file, c, rows)
                        for c in ("test_id", "machine_id")})
    out["plane"] = _one_of(frame["plane"].astype(str).str.strip().str.upper(), PLANES,
                           file, rows, "plane")
    out["direction"] = _one_of(frame["direction"].astype(str).str.strip().str.lower()
                               .map(DIRECTION_ALIASES).fillna(frame["direction"].astype(str)),
                               DIRECTIONS, file, rows, "direction")
    for col in ("angle_deg", "radius_mm", "feed_mm_min", "deviation_um"):
        out[col] = to_float(frame[col], file, col, rows)
    for col, what in (("radius_mm", "a nominal radius > 0 mm"),
                      ("feed_mm_min", "a feed > 0 mm/min")):
        bad = out[col] <= 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{out[col].iloc[i]:g} is not {what}", file=file,
                             row=row_of(rows, i), column=col)
    bad = out["deviation_um"].abs() > MAX_DEVIATION_UM
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{out['deviation_um'].iloc[i]:g} um is beyond a ballbar's +-1 mm "
                         "range; expected the radial deviation in um (measured minus nominal)",
                         file=file, row=row_of(rows, i), column="deviation_um")
    out["visit"] = (to_label(frame["visit"], file, "visit", rows) if "visit" in frame
                    else "1")
    if "started_at" in frame:
        out["started_at"] = to_datetime(frame["started_at"], file, "started_at", rows)
    if "operating_hours" in frame:
        out["operating_hours"] = to_float(frame["operating_hours"], file, "operating_hours",
                                          rows, allow_nan=True)
    _check_runs(out, file, rows)
    return out


def _one_of(values: pd.Series, allowed, file, rows, col: str) -> pd.Series:
    from features.readings.validation import row_of

    bad = ~values.isin(list(allowed))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{values.iloc[i]!r} is not a {col}; expected one of "
                         f"{', '.join(allowed)}", file=file, row=row_of(rows, i), column=col)
    return values


def _check_runs(frame: pd.DataFrame, file, rows) -> None:
    """Each run (test and direction) keeps one machine, plane, visit, radius and feed, holds
    enough readings and leaves no gap wider than ``MAX_GAP_DEG``."""
    from features.readings.validation import row_of

    for (test, direction), run in frame.groupby(["test_id", "direction"], sort=False):
        first = run.index[0]
        for col in CIRCLE_KEYS:
            changed = run[col].ne(run[col].iloc[0])
            if changed.any():
                i = int(changed.idxmax())
                raise InputError(f"test {test!r} {direction} changes {col} within the run; "
                                 "expected one value per run", file=file,
                                 row=row_of(rows, i), column=col)
        where = f"test {test!r} {direction}"
        if len(run) < MIN_READINGS:
            raise InputError(f"{where} has {len(run)} readings; expected at least "
                             f"{MIN_READINGS} round the circle", file=file,
                             row=row_of(rows, first), column="angle_deg")
        radius = run["radius_mm"].iloc[0]
        if (run["deviation_um"] - radius).abs().median() < 0.01 * radius:
            raise InputError(f"{where}: deviation_um holds the nominal radius {radius:g} mm or "
                             "close to it; expected the radial deviation in um (measured minus "
                             "nominal)", file=file, row=row_of(rows, first), column="deviation_um")
        span = float(run["deviation_um"].max() - run["deviation_um"].min())
        if span < RESOLUTION_UM:
            raise InputError(f"{where}: deviation_um spans {span:.3g} um round the circle, less "
                             f"than a ballbar's {RESOLUTION_UM:g} um resolution: the column is "
                             "likely in mm (every value 1000 times too small); expected the "
                             "radial deviation in um", file=file, row=row_of(rows, first),
                             column="deviation_um")
        gap = largest_gap_deg(run["angle_deg"].to_numpy())
        if gap > MAX_GAP_DEG:
            raise InputError(f"{where} leaves a gap of {gap:.0f} deg without readings; "
                             f"expected a circle or an arc with no gap over {MAX_GAP_DEG:g} "
                             "deg", file=file, row=row_of(rows, first), column="angle_deg")
    for key, circle in frame.groupby(list(CIRCLE_KEYS), sort=False):
        for direction, tests in circle.groupby("direction")["test_id"]:
            names = list(dict.fromkeys(tests))
            if len(names) > 1:
                i = int(tests.index[tests.ne(names[0])][0])
                raise InputError(
                    f"machine {key[0]!r} plane {key[1]} visit {key[2]!r} (R {key[3]:g} mm, "
                    f"F {key[4]:g} mm/min) has {direction} runs {names[0]!r} and {names[1]!r}; "
                    "expected one run per direction (give repeats their own visit)",
                    file=file, row=row_of(rows, i), column="test_id")


def small_span_note(frame: pd.DataFrame) -> str | None:
    """A note on the runs of the checked table (``read_circles``) whose deviations span less
    than ``PLAUSIBLE_SPAN_UM``: too little for a machine tool's circular test, as a column in
    mm would be; None when every run spans more."""
    spans = frame.groupby(["test_id", "direction"], sort=False)["deviation_um"].agg(
        lambda v: v.max() - v.min())
    small = spans[spans < PLAUSIBLE_SPAN_UM]
    if small.empty:
        return None
    runs = ", ".join(f"{test!r} {direction} {span:.2f} um" for (test, direction), span
                     in small.items())
    return (f"deviation_um spans less than {PLAUSIBLE_SPAN_UM:g} um round the circle in {runs}: "
            "less than a machine tool's circular test shows; if the column is in mm, every "
            "figure is 1000 times too small")


def largest_gap_deg(angle_deg: np.ndarray) -> float:
    """The widest angular interval without a reading [deg], round the circle."""
    a = np.sort(np.mod(angle_deg, 360.0))
    return float(np.max(np.diff(np.append(a, a[0] + 360.0))))


def circles(frame: pd.DataFrame) -> list[Circle]:
    """The checked table (``read_circles``) as circular tests, in the order of the file."""
    out = []
    for key, rows in frame.groupby(list(CIRCLE_KEYS), sort=False):
        runs = {}
        for direction in DIRECTIONS:
            captured = rows[rows["direction"] == direction]
            if len(captured):
                # the travel in the file's order (capture), before sorting by angle
                travel = pd.Series(travel_deg(direction, captured["angle_deg"].to_numpy(float)),
                                   index=captured.index)
                run = captured.sort_values("angle_deg", kind="stable")
                runs[direction] = Run(str(run["test_id"].iloc[0]), direction,
                                      run["angle_deg"].to_numpy(float),
                                      run["deviation_um"].to_numpy(float),
                                      travel[run.index].to_numpy(float))
        machine, plane, visit, radius, feed = key
        out.append(Circle(str(machine), str(plane), str(visit), float(radius), float(feed),
                          runs))
    return out


# --------------------------------------------------------------------------- ISO 230-4


def centre_fit(angle_deg: np.ndarray, deviation_um: np.ndarray) -> tuple[float, float, float]:
    """The least-squares circle of one run, linearised for deviations much smaller than R.

    .. math:: \\Delta r(\\theta) \\approx r_0 + c_1 \\cos\\theta + c_2 \\sin\\theta

    Returns
    -------
    r0, c1, c2 : float
        Mean radial deviation [um] and the centre's offset along the plane's first and
        second axis [um] (ISO 230-4: the paths are evaluated about the least-squares centre).
    """
    t = np.radians(angle_deg)
    design = np.column_stack([np.ones_like(t), np.cos(t), np.sin(t)])
    (r0, c1, c2), *_ = np.linalg.lstsq(design, deviation_um, rcond=None)
    return float(r0), float(c1), float(c2)


def centred(angle_deg: np.ndarray, deviation_um: np.ndarray) -> np.ndarray:
    """Radial deviation about the run's least-squares centre [um] (its mean radius kept)."""
    _, c1, c2 = centre_fit(angle_deg, deviation_um)
    t = np.radians(angle_deg)
    return deviation_um - c1 * np.cos(t) - c2 * np.sin(t)


def circular_deviation(angle_deg: np.ndarray, deviation_um: np.ndarray) -> float:
    """ISO 230-4 circular deviation G [um]: the radial width of the band that holds the whole
    path, about the least-squares centre, :math:`G = \\max \\Delta r - \\min \\Delta r`."""
    path = centred(angle_deg, deviation_um)
    return float(path.max() - path.min())


def hysteresis(cw: Run, ccw: Run) -> float:
    """ISO 230-4 circular hysteresis H [um]: the largest radial difference between the CW and
    CCW paths at the same angle, each about its own least-squares centre.

    The CCW path is interpolated at the CW angles (linearly, round the circle); angles where
    either run has a gap wider than three of its reading spacings are left out.
    """
    a_cw, a_ccw = np.mod(cw.angle_deg, 360.0), np.mod(ccw.angle_deg, 360.0)
    order = np.argsort(a_ccw)
    a_ccw, path_ccw = a_ccw[order], centred(ccw.angle_deg, ccw.deviation_um)[order]
    other = np.interp(a_cw, a_ccw, path_ccw, period=360.0)
    near = _covered(a_cw, a_ccw)
    diff = np.abs(centred(cw.angle_deg, cw.deviation_um) - other)[near]
    return float(diff.max()) if diff.size else float("nan")


def _covered(at: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Whether each angle of ``at`` (in [0, 360)) lies within three reading spacings of the
    sorted ``angles`` (in [0, 360)), round the circle."""
    a = np.unique(angles)
    ring = np.concatenate([a - 360.0, a, a + 360.0])
    step = np.median(np.diff(np.append(a, a[0] + 360.0)))
    i = np.clip(np.searchsorted(ring, at), 1, len(ring) - 1)
    nearest = np.minimum(np.abs(at - ring[i - 1]), np.abs(ring[i] - at))
    return nearest <= 3.0 * step
