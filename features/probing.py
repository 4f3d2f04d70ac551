"""The probing contract (data contract section 13): calibration spheres probed on a five-axis
machine's rotary table, one row per measured sphere centre.

The names of the 12 geometric errors of the two rotary axes are seed 003's Table 1 with units
in the names (``delta_x_A_um`` ... ``eps_gamma_C_urad``); the twin
(``models.physics.rotary_probing``) and the identification (``models.machine.kinematics``) both
read them from here, so that a name means the same in the truth a twin writes and in what the
job reports.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.errors import InputError

# kinematics -> (tilting axis, its rotation axis index in x, y, z; the table axis on it)
KINEMATICS = {"AC-table": ("A", 0, "C"), "BC-table": ("B", 1, "C")}
TRANSLATIONS = ("x", "y", "z")
ANGLES = ("alpha", "beta", "gamma")  # rotations about X, Y, Z (seed 003 Table 1)
POINT_COLUMNS = ("sphere_x_mm", "sphere_y_mm", "sphere_z_mm")
MEASURED_COLUMNS = ("x_mm", "y_mm", "z_mm")
REQUIRED = ("test_id", "machine_id", "kinematics", "sphere", *POINT_COLUMNS, "c_deg",
            "direction", *MEASURED_COLUMNS)
OPTIONAL = ("visit", "started_at")
# A probed centre further than this from where an ideal machine puts it is not a centre in mm
# (a unit slip, a wrong sphere position): 5 mm is far beyond any rotary axis's error.
MAX_DEVIATION_MM = 5.0
# Below this largest |angle| with several distinct angles, the angles look like radians.
RADIAN_LIMIT = 2.0 * np.pi


def error_names(kinematics: str) -> tuple[str, ...]:
    """The 12 error names of a kinematics, seed 003 Table 1 order: per axis (tilting, then
    table) the three translations [um], then the three angles [urad].

    >>> error_names("AC-table")[:4]
    ('delta_x_A_um', 'delta_y_A_um', 'delta_z_A_um', 'eps_alpha_A_urad')
    """
    tilt, _, table = KINEMATICS[kinematics]
    return tuple(name for axis in (tilt, table) for name in (
        *(f"delta_{t}_{axis}_um" for t in TRANSLATIONS),
        *(f"eps_{a}_{axis}_urad" for a in ANGLES)))


def axes_of(kinematics: str) -> tuple[str, str]:
    """(tilting axis, table axis): ("A", "C") or ("B", "C")."""
    tilt, _, table = KINEMATICS[kinematics]
    return tilt, table


def angle_column(axis: str) -> str:
    return f"{axis.lower()}_deg"


def read_probes(data, parameter: str = "data") -> pd.DataFrame:
    """Read and check a probing table (data contract section 13).

    Parameters
    ----------
    data : str, path-like or DataFrame
        A CSV or Parquet file, or a frame with the contract's columns.
    parameter : str
        The caller's parameter that passed ``data`` (named in errors about a frame).

    Returns
    -------
    DataFrame
        The contract's columns typed (labels as text, numbers as float, ``direction`` +1/-1,
        the tilting axis's angle as ``a_deg`` or ``b_deg`` as the kinematics says, ``visit``
        ``"1"`` where absent, ``started_at`` as UTC date-times where given).

    Raises
    ------
    InputError
        A missing column, a value that is not what the contract expects (a kinematics not
        known, a direction other than +1/-1, angles that look like radians, a centre millimetres
        away from where the machine puts it), naming the file, row and column.
    """
    from features.readings.io import read_table_rows

    if isinstance(data, pd.DataFrame):
        frame, file, rows = data.reset_index(drop=True), None, pd.Series(data.index) + 2
        if frame.empty:
            raise InputError("no probed centres: the frame is empty", parameter=parameter)
    else:
        frame, file, rows = read_table_rows(data)
    return _checked(frame, file, rows)


def _checked(frame: pd.DataFrame, file, rows) -> pd.DataFrame:
    from features.readings.validation import row_of, to_datetime, to_float, to_label

    known = {c.lower(): c for c in (*REQUIRED, "a_deg", "b_deg", *OPTIONAL)}
    frame = frame.rename(columns={c: known[str(c).strip().lower()] for c in frame.columns
                                  if str(c).strip().lower() in known})
    missing = [c for c in REQUIRED if c not in frame]
    if missing:
        raise InputError(f"missing required column {missing[0]!r} of a probing table "
                         f"(required: {', '.join(REQUIRED)} and a_deg or b_deg)", file=file,
                         row=1, column=missing[0])
    out = pd.DataFrame({c: to_label(frame[c], file, c, rows)
                        for c in ("test_id", "machine_id", "kinematics", "sphere")})
    bad = ~out["kinematics"].isin(list(KINEMATICS))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{out['kinematics'].iloc[i]!r} is not a kinematics; expected one of "
                         f"{', '.join(KINEMATICS)}", file=file, row=row_of(rows, i),
                         column="kinematics")
    for kinematics in out["kinematics"].unique():
        column = angle_column(axes_of(kinematics)[0])
        if column not in frame:
            raise InputError(f"missing required column {column!r}: the {kinematics} "
                             "kinematics tilts its table about that axis", file=file, row=1,
                             column=column)
    for col in (*POINT_COLUMNS, *MEASURED_COLUMNS, "c_deg"):
        out[col] = to_float(frame[col], file, col, rows)
    for col in ("a_deg", "b_deg"):
        if col in frame:
            needed = out["kinematics"].map(
                {k: angle_column(axes_of(k)[0]) == col for k in KINEMATICS})
            values = to_float(frame[col], file, col, rows, allow_nan=True)
            missing_angle = needed & values.isna()
            if missing_angle.any():
                i = int(np.flatnonzero(missing_angle)[0])
                raise InputError("empty angle; expected the commanded angle in degrees",
                                 file=file, row=row_of(rows, i), column=col)
            out[col] = values
    direction = to_float(frame["direction"], file, "direction", rows)
    bad = ~direction.isin([1.0, -1.0])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{direction.iloc[i]:g} is not a direction; expected +1 (the angle "
                         "approached increasing) or -1 (decreasing)", file=file,
                         row=row_of(rows, i), column="direction")
    out["direction"] = direction.astype(int)
    out["visit"] = (to_label(frame["visit"], file, "visit", rows) if "visit" in frame
                    else "1")
    if "started_at" in frame:
        out["started_at"] = to_datetime(frame["started_at"], file, "started_at", rows)
    _check_degrees(out, file)
    _check_centres(out, file, rows)
    return out


def _check_degrees(out: pd.DataFrame, file) -> None:
    """Angles in radians would be read as a machine that barely turned: refused when every
    angle of a machine lies within 2 pi and they take several values (a probing cycle in
    degrees turns its table tens of degrees)."""
    for (machine, kinematics), part in out.groupby(["machine_id", "kinematics"], sort=True):
        tilt = angle_column(axes_of(kinematics)[0])
        angles = np.r_[part[tilt].to_numpy(), part["c_deg"].to_numpy()]
        largest = float(np.max(np.abs(angles)))
        if 0 < largest <= RADIAN_LIMIT and len(np.unique(np.round(angles, 9))) > 2:
            raise InputError(
                f"machine {machine}: every angle lies within +-{largest:.3g} (largest "
                f"|{tilt}|, |c_deg|); the angles look like radians: the contract takes "
                "degrees (multiply by 180/pi)", file=file,
                column=tilt if np.max(np.abs(part[tilt])) >= largest else "c_deg")


def _check_centres(out: pd.DataFrame, file, rows) -> None:
    """A measured centre millimetres away from where an ideal machine puts the sphere: the
    wrong unit, sphere or angle."""
    from features.readings.validation import row_of

    nominal = nominal_centres_mm(out)
    measured = out[list(MEASURED_COLUMNS)].to_numpy(float)
    off = np.linalg.norm(measured - nominal, axis=1)
    bad = off > MAX_DEVIATION_MM
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"the measured centre lies {off[i]:.1f} mm from where the angles put sphere "
            f"{out['sphere'].iloc[i]!r} (more than {MAX_DEVIATION_MM:g} mm); expected the "
            "sphere's table-frame centre and the measured centre in mm, the angles in degrees",
            file=file, row=row_of(rows, i), column="x_mm")


def rotation(axis_index: int, angle_rad) -> np.ndarray:
    """Right-hand rotation matrices about +X (0), +Y (1) or +Z (2), shape (..., 3, 3)
    (seed 003 eq. 1)."""
    angle_rad = np.asarray(angle_rad, float)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = [(1, 2), (2, 0), (0, 1)][axis_index]
    m = np.zeros((*c.shape, 3, 3))
    m[..., axis_index, axis_index] = 1.0
    m[..., i, i], m[..., i, j], m[..., j, i], m[..., j, j] = c, -s, s, c
    return m


def nominal_centres_mm(frame: pd.DataFrame) -> np.ndarray:
    """Where an ideal machine puts each row's sphere: R_tilt(a) R_z(c) q [mm], shape (n, 3)."""
    q = frame[list(POINT_COLUMNS)].to_numpy(float)
    out = np.empty_like(q)
    for kinematics, idx in frame.groupby("kinematics", sort=False).indices.items():
        tilt, axis_index, _ = KINEMATICS[kinematics]
        part = frame.iloc[idx]
        r_tilt = rotation(axis_index, np.radians(part[angle_column(tilt)].to_numpy(float)))
        r_c = rotation(2, np.radians(part["c_deg"].to_numpy(float)))
        out[idx] = np.einsum("nij,njk,nk->ni", r_tilt, r_c, q[idx])
    return out
