"""Five-axis rotary errors from probed spheres: the 12 geometric errors of a dual turntable
(seed 003 Table 1), each rotary axis's play, and the error field over the workspace.

>>> import backlash as bl
>>> result = bl.kinematics("experiments/data/kinematics/probes.csv")   # doctest: +SKIP
>>> result.to_dict()["machines"][0]["play_arcsec"]                       # doctest: +SKIP
{'A': 9.8..., 'C': 4.1...}

The numbers come from ``models.machine.kinematics`` (linear least squares on the error chain,
the rank from its SVD); this module reads the table, checks the angles, and shapes the result.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from numbers import Real
from pathlib import Path

from features.readings.errors import InputError
from pipeline.results import Result
from pipeline.steps.constraints import Interval, StrOptions
from pipeline.steps.parameters import Param

# Controllers whose rotary-axis backlash is a machine parameter of its own (written alone, so
# the axis's position-error table on the machine is left as it is).
ROTARY_BACKLASH = ("siemens", "heidenhain")
TILT_TABLE = (0.0, 30.0, 60.0, 90.0)     # seed 003 Table 4 (C = 0) and Table 5 (tilt = 0)
FIELD_TILTS = (0.0, 30.0, 45.0, 60.0, 90.0)  # seed 003 Figure 11
_PATHS = (str, os.PathLike)

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{probes}"],
    {"data": "{probes}"},
)

PARAMETERS = {
    "data": Param((*_PATHS, "pandas.DataFrame"), flag="PROBES"),
    "at": Param((*_PATHS, "pandas.DataFrame", None), metavar="POINTS.csv"),
    "workspace_mm": Param((Interval(Real, 0, 5000, closed="neither"),), metavar="MM"),
    "one_sphere": Param(("boolean",)),
    "controller": Param((None, StrOptions(set(ROTARY_BACKLASH))), choices=ROTARY_BACKLASH),
    "out": Param((*_PATHS, None), "folder for kinematics.json, errors.csv, field.csv (with "
                 "--at), kinematics.html and its plots", metavar="DIR", output="folder"),
    "store": Param((*_PATHS, None), "fleet store (folder or postgresql:// URL) to record each "
                   "rotary axis's errors and play in (docs/store.md)", metavar="STORE"),
}


@dataclass
class MachineKinematics:
    """One machine's (and visit's) identification.

    Attributes
    ----------
    machine_id, visit, test_id, kinematics : str
    ident : models.machine.kinematics.Identification
    tables : dict
        Seed 003 Tables 4-5: ``"tilt"`` (per tilt angle at C = 0) and ``"c"`` (per C at tilt
        0) -> angle -> ``{"min_um", "max_um"}`` over the workspace cube.
    date : str or None
        ISO day of its earliest ``started_at``.
    """

    machine_id: str
    visit: str
    test_id: str
    kinematics: str
    ident: object
    tables: dict
    date: str | None = None

    def to_dict(self) -> dict:
        from features.probing import axes_of, error_names
        from models.machine.kinematics import play_names

        i = self.ident
        names = error_names(self.kinematics)
        tilt, table = axes_of(self.kinematics)
        plays = dict(zip((tilt, table), play_names(self.kinematics)))
        return {"machine_id": self.machine_id, "visit": self.visit, "test_id": self.test_id,
                "kinematics": self.kinematics,
                "errors": {n: _round(i.value(n)) for n in names},
                "errors_u": {n: _round(i.u(n)) for n in names},
                "not_identifiable": [g for g in i.groups],
                "identifiable_combinations": [
                    {k: (_round(v) if k in ("value", "u") else v) for k, v in c.items()}
                    for c in i.combinations],
                "play_arcsec": {a: _round(i.value(n)) for a, n in plays.items()},
                "play_u_arcsec": {a: _round(i.u(n)) for a, n in plays.items()},
                "residual_rms_um": _round(i.residual_rms_um), "points": i.points,
                "rank": i.rank,
                "comprehensive_error_mm": {
                    key: {f"{angle:g}": {k.replace("_um", "_mm"): _round(
                        v / 1000 if v is not None else None, 6) for k, v in cell.items()}
                          for angle, cell in rows.items()}
                    for key, rows in self.tables.items()}}


def _round(value, digits: int = 4):
    return None if value is None else round(float(value), digits)


@dataclass
class KinematicsResult(Result):
    """Every machine's rotary errors, plays and (with ``at``) the predicted field.

    Attributes
    ----------
    machines : list of MachineKinematics
    field : DataFrame or None
        ``machine_id``, the points' columns, ``dx_um``, ``dy_um``, ``dz_um``, their ``_u_um``
        and ``error_um`` (SCHEMA.md section 13), when ``at`` was given.
    compensation : dict
        File name -> its text: each rotary axis's play as ``controller``'s backlash parameter.
    source : str
    workspace_mm : float
    """

    machines: list
    field: object = None
    compensation: dict = dataclass_field(default_factory=dict)
    source: str = ""
    workspace_mm: float = 200.0
    parameters: dict = dataclass_field(default_factory=dict)
    recorded: object = None

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan({"source": self.source,
                          "machines": [m.to_dict() for m in self.machines],
                          "compensation_files": sorted(self.compensation),
                          "notes": list(self.notes)})

    def table(self) -> str:
        """Per machine: the plays, then every error (or its group) with its uncertainty."""
        lines = []
        for m in self.machines:
            j = m.to_dict()
            plays = ", ".join(f"{a} {v} ± {j['play_u_arcsec'][a]} arcsec"
                              for a, v in j["play_arcsec"].items())
            lines.append(f"{m.machine_id} visit {m.visit} ({m.kinematics}): play {plays}; "
                         f"residual {j['residual_rms_um']} um rms over {j['points']} centres")
            for name, value in j["errors"].items():
                shown = (f"{value} ± {j['errors_u'][name]}" if value is not None
                         else "not identifiable")
                lines.append(f"  {name:<18} {shown}")
            for combo in j["identifiable_combinations"]:
                lines.append(f"  {combo['label']} = {combo['value']} ± {combo['u']}")
        return "\n".join(lines)

    def write(self, out) -> dict[str, Path]:
        """Under ``out``: ``kinematics.json``, ``errors.csv`` (one row per machine and
        parameter), ``field.csv`` (with ``at``), the controller files, ``kinematics.html``
        with seed 003's Tables 4-5 and a field plot per machine (Figure 11's angles)."""
        import pandas as pd

        from features.readings.fileio import atomic_path, write_files, write_json
        from pipeline.reports.kinematics_report import write_report

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        self.files = {"json": write_json(out / "kinematics.json", self.to_dict())}
        rows = []
        for m in self.machines:
            i = m.ident
            rows += [{"machine_id": m.machine_id, "visit": m.visit, "parameter": n,
                      "value": i.value(n), "u": i.u(n),
                      "group": " ".join(next((g for g in i.groups if n in g), []))}
                     for n in i.names]
        frames = {"errors": pd.DataFrame(rows)}
        if self.field is not None:
            frames["field"] = self.field
        for role, frame in frames.items():
            with atomic_path(out / f"{role}.csv") as tmp:
                frame.to_csv(tmp, index=False)
            self.files[role] = out / f"{role}.csv"
        if self.compensation:
            written = write_files(out, {n: t.encode() for n, t in self.compensation.items()})
            self.files.update({f"controller {n}": p for n, p in written.items()})
        self.files.update(write_report(self, out))
        return self.files


def kinematics(data, *, at=None, workspace_mm: float = 200.0, one_sphere: bool = False,
               controller: str | None = None) -> KinematicsResult:
    """Identify the rotary axes' 12 geometric errors and plays from probed spheres.

    Parameters
    ----------
    data : str, path-like or DataFrame
        A probing table, CSV or Parquet (SCHEMA.md section 13, docs/kinematics.md).
    at : str, path-like or DataFrame, optional
        Workpiece points (``x_mm``, ``y_mm``, ``z_mm`` in the table frame) and angles
        (``a_deg`` or ``b_deg``, ``c_deg``) [mm, deg], CSV or Parquet: the error field is
        predicted there for every machine (the result's ``field``, ``field.csv`` in the
        output folder).
    workspace_mm : float
        Half width W of the workpiece cube (x, y in [-W, W], z in [0, W]) [mm] over which the
        report's tables (seed 003's Tables 4-5: smallest and largest comprehensive error) and
        field plots are taken.
    one_sphere : bool
        Accept a machine probed on a single sphere (off the C axis) with a note: its 12
        errors are determined, but nothing checks that the table moves as one rigid body (a
        second sphere at another radius and height does); otherwise such a machine is refused.
    controller : {"siemens", "heidenhain"}, optional
        Write each rotary axis's play [deg] as that controller's backlash machine parameter
        (SINUMERIK MD32450, Heidenhain MP710), in the output folder.

    Returns
    -------
    KinematicsResult
        Per machine and visit: the 12 errors [um, urad] with standard uncertainties (None for
        errors the probing cannot separate, with their group and identifiable combinations),
        the plays [arcsec], the residual [um], Tables 4-5 [mm].

    Raises
    ------
    InputError
        A table that breaks the contract (a missing column, angles that look like radians),
        angles that do not span each axis, a single sphere (unless ``one_sphere``; always when
        it leaves errors inseparable).

    References
    ----------
    S. Wu et al. (seed 003): eq. 6, Table 1, eq. 12-13, Tables 4-5; ISO 10791-6.
    """
    from features.probing import read_probes
    from features.readings.errors import note

    probes = read_probes(data)
    points = _points(at) if at is not None else None
    source = str(data) if isinstance(data, (str, os.PathLike)) else "<frame>"
    machines, notes = [], []
    for (machine, visit), part in probes.groupby(["machine_id", "visit"], sort=True):
        found, said = _identify(part, source, workspace_mm, one_sphere)
        machines.append(found)
        notes += said
    result = KinematicsResult(machines, source=source, workspace_mm=workspace_mm,
                              parameters={"workspace_mm": workspace_mm,
                                          "one_sphere": one_sphere, "controller": controller})
    if points is not None:
        result.field = _field(machines, points)
    if controller is not None:
        result.compensation = _compensation(machines, controller, probes)
        notes.append(f"{controller}: only the rotary axes' backlash parameter is written; "
                     "their position-error tables on the machine are left as they are")
    for text in notes:
        note(text)
    result.notes = notes
    return result


def _identify(part, source: str, workspace_mm: float, one_sphere: bool = False):
    """One machine and visit: checks, identification, Tables 4-5, notes."""
    from features.probing import (
        MEASURED_COLUMNS,
        POINT_COLUMNS,
        angle_column,
        axes_of,
        nominal_centres_mm,
    )
    from models.machine import kinematics as km

    machine, visit = str(part["machine_id"].iloc[0]), str(part["visit"].iloc[0])
    kinds = part["kinematics"].unique()
    if len(kinds) > 1:
        raise InputError(f"machine {machine}: rows name kinematics {', '.join(kinds)}; a "
                         "machine has one", file=source, column="kinematics")
    kin = str(kinds[0])
    tilt, _ = axes_of(kin)
    column = angle_column(tilt)
    problem = km.span_problem(part[column], part["c_deg"], tilt)
    if problem:
        raise InputError(f"machine {machine}: {problem}", file=source, column=column)
    q = part[list(POINT_COLUMNS)].to_numpy(float)
    dev = (part[list(MEASURED_COLUMNS)].to_numpy(float) - nominal_centres_mm(part)) * 1e3
    ident = km.identify(kin, q, part[column], part["c_deg"], part["direction"], dev)
    spheres = part["sphere"].unique()
    structural = set(map(tuple, km.structural_groups(kin)))
    extra = [g for g in ident.groups if tuple(g) not in structural]
    if len(spheres) == 1 and extra:
        raise InputError(
            f"machine {machine}: one sphere only ({spheres[0]}): with it the probing cannot "
            f"separate {'; '.join(' from '.join(g) for g in extra)}; probe a second sphere "
            "at another radius from C and another height", file=source, column="sphere")
    if len(spheres) == 1 and not one_sphere:
        raise InputError(
            f"machine {machine}: one sphere only ({spheres[0]}): its errors are determined, but "
            "what a second sphere gives is lost: the check that the table moves as one rigid "
            "body; probe a second sphere at another radius and height, or accept it with "
            "--one-sphere", file=source, column="sphere")
    notes = []
    if len(spheres) == 1:
        notes.append(f"machine {machine}: one sphere only ({spheres[0]}): the 12 errors are "
                     "determined, but nothing checks that the table moves as one rigid "
                     "body (a second sphere at another radius and height does)")
    if extra:
        notes.append(f"machine {machine}: the probing cannot separate "
                     f"{'; '.join(', '.join(g) for g in extra)} (beyond the pairs no probing "
                     "separates)")
    if set(part["direction"]) != {1, -1}:
        notes.append(f"machine {machine}: one approach direction only: the plays are not "
                     "identifiable (they need both)")
    grid = km.workspace_grid(workspace_mm)
    tables = {"tilt": {a: km.extremes(ident, grid, a, 0.0) for a in TILT_TABLE},
              "c": {c: km.extremes(ident, grid, 0.0, c) for c in TILT_TABLE}}
    date = None
    if "started_at" in part and part["started_at"].notna().any():
        date = part["started_at"].min().date().isoformat()
    return MachineKinematics(machine, visit, ",".join(sorted(part["test_id"].unique())), kin,
                             ident, tables, date), notes


def _points(at):
    """The ``at`` table: x_mm, y_mm, z_mm, a_deg or b_deg, c_deg."""
    import pandas as pd

    from features.readings.formats import read_table
    from features.readings.io import check_readable

    if isinstance(at, pd.DataFrame):
        frame, file = at.reset_index(drop=True), None
    else:
        check_readable(Path(at))
        frame, _ = read_table(Path(at))
        file = at
    frame = frame.rename(columns={c: str(c).strip().lower() for c in frame.columns})
    for col in ("x_mm", "y_mm", "z_mm", "c_deg"):
        if col not in frame:
            raise InputError(f"missing required column {col!r} of the points (x_mm, y_mm, "
                             "z_mm, a_deg or b_deg, c_deg)", file=file, column=col,
                             parameter=None if file else "at")
    if "a_deg" not in frame and "b_deg" not in frame:
        raise InputError("missing required column 'a_deg' (or 'b_deg') of the points",
                         file=file, column="a_deg", parameter=None if file else "at")
    keep = [c for c in ("x_mm", "y_mm", "z_mm", "a_deg", "b_deg", "c_deg") if c in frame]
    try:
        return frame[keep].astype(float)
    except (TypeError, ValueError):
        raise InputError("the points' columns must be numbers", file=file,
                         parameter=None if file else "at") from None


def _field(machines: list, points):
    """``field`` for every machine at every point (SCHEMA.md section 13)."""
    import pandas as pd

    from features.probing import angle_column, axes_of
    from models.machine.kinematics import field_um

    frames = []
    for m in machines:
        column = angle_column(axes_of(m.kinematics)[0])
        if column not in points:
            raise InputError(f"machine {m.machine_id} is {m.kinematics}: the points need "
                             f"{column!r}", parameter="at", column=column)
        dp, u, e = field_um(m.ident, points[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                            points[column].to_numpy(), points["c_deg"].to_numpy())
        frame = pd.concat([pd.DataFrame({"machine_id": m.machine_id}, index=points.index),
                           points], axis=1)
        for k, axis in enumerate("xyz"):
            frame[f"d{axis}_um"] = dp[:, k]
        for k, axis in enumerate("xyz"):
            frame[f"d{axis}_u_um"] = u[:, k]
        frame["error_um"] = e
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _compensation(machines: list, controller: str, probes) -> dict:
    """Each rotary axis's play as ``controller``'s backlash parameter: a flat profile with the
    play as its reversal (mean_up = -b/2, mean_down = +b/2 [arcsec]) through the controller's
    own writer, keeping its parameters file only."""
    import numpy as np

    from features.probing import angle_column, axes_of
    from features.readings.fileio import MemoryFolder
    from models.machine.kinematics import play_names
    from pipeline.compensation import CONTROLLERS
    from pipeline.compensation.common import Options
    from pipeline.compensation.profile import AxisProfile

    folder, files = MemoryFolder(), {}
    record = CONTROLLERS[controller]
    latest = {}
    for m in machines:  # the machine's last visit in the file
        latest[m.machine_id] = m
    for m in latest.values():
        for axis, name in zip(axes_of(m.kinematics), play_names(m.kinematics)):
            play, u = m.ident.value(name), m.ident.u(name)
            if play is None:
                continue
            column = "c_deg" if axis == "C" else angle_column(axis)
            part = probes[probes["machine_id"] == m.machine_id]
            target = np.unique(part[column].to_numpy(float))
            n = len(target)
            profile = AxisProfile(m.machine_id, axis, target, np.full(n, -max(play, 0) / 2),
                                  np.full(n, max(play, 0) / 2), np.full(n, u), np.full(n, u),
                                  "measured", notes=[(f"rotary play from probing "
                                                      f"(backlash kinematics): {play:.2f} "
                                                      f"± {u:.2f} arcsec")])
            written = record.writer(profile, folder, Options())
            kept = written["files"]["parameters"]
            files[kept.name] = kept.read_bytes().decode()
    return files
