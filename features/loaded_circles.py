"""Loaded circular tests (LDBB, data contract section 12): the circle table of section 11 plus the
load and the centre of every run; its reader and the grouping into centres.

The circle columns are checked by ``features.circle.read_circles`` (the same messages, rows
and limits as ``backlash circle``); this module checks what section 12 adds: ``load_n`` and
``centre_x_mm``, ``centre_y_mm``, ``centre_z_mm`` on every row, one value of each per run, and
at least two loads at every centre (the deflection is what changes with the load).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.readings.errors import InputError

LOAD = "load_n"
CENTRE = ("centre_x_mm", "centre_y_mm", "centre_z_mm")
ADDED = (LOAD, *CENTRE)
# One centre: one machine, plane, visit and centre; its runs differ by load and direction.
CENTRE_KEYS = ("machine_id", "plane", "visit", *CENTRE)


@dataclass(frozen=True)
class Centre:
    """The runs of one machine, plane and visit about one centre.

    Attributes
    ----------
    machine_id, plane, visit : str
    centre_mm : ndarray, shape (3,)
    runs : list of (direction, load_n, angle_deg, deviation_um)
        Every run, in the order of the file.
    first_row : int
        The row of its first reading (for messages).
    """

    machine_id: str
    plane: str
    visit: str
    centre_mm: np.ndarray
    runs: list
    first_row: int

    @property
    def loads_n(self) -> list[float]:
        return sorted({float(load) for _, load, *_ in self.runs})

    def name(self) -> str:
        x, y, z = self.centre_mm
        return (f"machine {self.machine_id!r} plane {self.plane} visit {self.visit!r} centre "
                f"({x:g}, {y:g}, {z:g}) mm")


def read_loaded_circles(data, parameter: str = "data") -> pd.DataFrame:
    """Read and check an LDBB table (data contract section 12).

    Parameters
    ----------
    data : str, path-like or DataFrame
        CSV or Parquet, or a frame of it.
    parameter : str
        The caller's parameter that passed ``data`` (named in errors about a frame).

    Returns
    -------
    DataFrame
        ``features.circle.read_circles``'s columns plus ``load_n`` [N], the centre [mm] and
        ``row`` (the reading's row in the file), one row per reading.

    Raises
    ------
    InputError
        What ``read_circles`` refuses; a missing ``load_n`` or centre column or value; a load
        or centre that changes within a run; naming the file, row and column.
    """
    from features import circle as fc
    from features.readings.io import read_table_rows
    from features.readings.validation import row_of, to_float

    if isinstance(data, pd.DataFrame):
        file, frame = None, data.reset_index(drop=True)
        rows = pd.Series(data.index)
        if frame.empty:
            raise InputError("no readings: the frame is empty", parameter=parameter)
    else:
        frame, file, rows = read_table_rows(data)
        if not isinstance(rows, pd.Series):  # consecutive rows from the first
            rows = pd.Series(np.arange(len(frame)) + rows)
    where = {"file": file} if file is not None else {"parameter": parameter}
    known = {c.lower(): c for c in ADDED}
    frame = frame.rename(columns={c: known[str(c).lower()] for c in frame.columns
                                  if str(c).lower() in known})
    for col in ADDED:
        if col not in frame:
            raise InputError(f"missing required column {col!r} of a loaded circular test "
                             f"(data contract section 12: the circle table plus "
                             f"{', '.join(ADDED)})",
                             row=1, column=col, **where)
    added = {col: to_float(frame[col], file, col, rows) for col in ADDED}
    run = [frame["test_id"].astype(str), frame["direction"].astype(str)]
    for col in ADDED:
        changed = added[col].ne(added[col].groupby(run, sort=False).transform("first"))
        if changed.any():
            i = int(np.flatnonzero(changed.to_numpy())[0])
            raise InputError(f"test {frame['test_id'].iloc[i]!r} changes {col} within the "
                             "run; expected one value per run", row=row_of(rows, i),
                             column=col, **where)
    # the circle columns, checked as backlash circle checks them; each run is a circle of its
    # own to read_circles (its visit names the run), since a centre holds a run per load
    keyed = frame.drop(columns=list(ADDED)).copy()
    keyed.index = rows.to_numpy()
    visit = keyed["visit"] if "visit" in keyed else pd.Series("1", keyed.index)
    keyed["visit"] = visit.astype(str) + " @ " + keyed["test_id"].astype(str)
    try:
        circles = fc.read_circles(keyed, parameter)
    except InputError as err:
        raise InputError(err.message, row=err.row, column=err.column, **where) from None
    circles["visit"] = circles["visit"].str.rsplit(" @ ", n=1).str[0]
    for col in ADDED:
        circles[col] = added[col].to_numpy()
    circles["row"] = rows.to_numpy()
    return circles


def centres(frame: pd.DataFrame) -> list[Centre]:
    """The checked table (``read_loaded_circles``) as centres, in the order of the file."""
    out = []
    for key, part in frame.groupby(list(CENTRE_KEYS), sort=False):
        machine, plane, visit, x, y, z = key
        runs = []
        for (_, direction), run in part.groupby(["test_id", "direction"], sort=False):
            run = run.sort_values("angle_deg", kind="stable")
            runs.append((str(direction), float(run[LOAD].iloc[0]),
                         run["angle_deg"].to_numpy(float), run["deviation_um"].to_numpy(float)))
        out.append(Centre(str(machine), str(plane), str(visit), np.array([x, y, z], float),
                          runs, int(part["row"].iloc[0])))
    return out


def check_loads(items: list[Centre], file=None, parameter: str = "data") -> None:
    """Every centre was run at two loads or more in one direction: the deflection is the part
    of the deviation that changes with the load.

    Raises
    ------
    InputError
        Every run at one load (naming it); else the first centre with a single load.
    """
    where = {"file": file} if file is not None else {"parameter": parameter}
    loads = sorted({load for c in items for load in c.loads_n})
    if len(loads) == 1:
        raise InputError(f"every run has load_n {loads[0]:g} N: the deflection is the part of "
                         "the deviation that changes with the load, so each centre needs runs "
                         "at two loads or more (e.g. 100, 300, 500 N)", row=items[0].first_row,
                         column=LOAD, **where)
    for c in items:
        by_direction = {}
        for direction, load, *_ in c.runs:
            by_direction.setdefault(direction, set()).add(load)
        if max(len(v) for v in by_direction.values()) < 2:
            raise InputError(f"{c.name()} was run at a single load ({c.loads_n[0]:g} N) in "
                             "each direction: its stiffness needs runs at two loads or more in "
                             "one direction", row=c.first_row, column=LOAD, **where)


POINT_COLUMNS = ("x_mm", "y_mm", "z_mm", "fx_n", "fy_n")


def read_points(data, parameter: str = "at") -> pd.DataFrame:
    """Points with quasi-static forces (data contract section 12's ``--at``): ``x_mm, y_mm, z_mm,
    fx_n, fy_n[, fz_n]`` and any other columns (kept), one row per point.

    Parameters
    ----------
    data : str, path-like or DataFrame
        CSV or Parquet, or a frame of it.
    parameter : str
        The caller's parameter (named in errors).

    Returns
    -------
    DataFrame
        The table with its columns typed (the required ones and ``fz_n`` as float).

    Raises
    ------
    InputError
        A missing column, an empty or non-numeric value, an empty table.
    """
    from features.readings.io import read_table_rows
    from features.readings.validation import to_float

    if isinstance(data, pd.DataFrame):
        file, frame, rows = None, data.reset_index(drop=True), pd.Series(data.index)
    else:
        frame, file, rows = read_table_rows(data)
        if not isinstance(rows, pd.Series):  # consecutive rows from the first
            rows = pd.Series(np.arange(len(frame)) + rows)
    where = {"file": file} if file is not None else {"parameter": parameter}
    if frame.empty:
        raise InputError("no points: the table is empty; expected x_mm, y_mm, z_mm, fx_n, "
                         "fy_n[, fz_n]", **where)
    known = {c: c for c in (*POINT_COLUMNS, "fz_n")}
    frame = frame.rename(columns={c: known[str(c).lower()] for c in frame.columns
                                  if str(c).lower() in known})
    for col in POINT_COLUMNS:
        if col not in frame:
            raise InputError(f"missing required column {col!r} of the points (x_mm, y_mm, z_mm, "
                             "fx_n, fy_n[, fz_n])", row=1, column=col, **where)
    out = frame.copy()
    for col in (*POINT_COLUMNS, "fz_n"):
        if col in frame:
            out[col] = to_float(frame[col], file, col, rows).to_numpy()
    return out
