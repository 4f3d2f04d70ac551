"""Static stiffness across the workspace from loaded double-ballbar (LDBB) circles.

>>> import backlash as bl
>>> result = bl.stiffness("experiments/data/stiffness/ldbb.csv", ram_top_mm=200)  # doctest: +SKIP
>>> result.machines[0]["centres"][0]["stiffness_n_per_um"]                       # doctest: +SKIP
{'X': 17.4..., 'Y': 18.0...}

Each centre's runs at several loads give the plane's compliance (``models.machine.stiffness``:
per angle the deviation regressed on the load; the slope is :math:`u^T C u`); the centres give
a map over the workspace whose form cross-validation chooses; ``at`` predicts the deflection
under given forces where no circle was run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from pipeline.results import Result
from pipeline.steps.constraints import Interval, StrOptions
from pipeline.steps.parameters import Param

FORMS = ("auto", "constant", "linear", "cubic", "quadratic")

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{ldbb}", "--ram-top", "200"],
    {"data": "{ldbb}", "ram_top_mm": 200.0},
)

PARAMETERS = {
    "data": Param((str, os.PathLike, "pandas.DataFrame"), flag="FILE"),
    "at": Param((str, os.PathLike, "pandas.DataFrame", None), metavar="POINTS.csv"),
    "ram_top_mm": Param((None, Interval(Real, None, None, closed="neither")), flag="--ram-top",
                        metavar="MM"),
    "form": Param((StrOptions(set(FORMS)),), flag="--map", choices=FORMS),
    "out": Param((str, os.PathLike, None), "output folder: stiffness.json, centres.csv and, "
                 "with --at, deflection.csv", metavar="DIR", output="folder"),
    "store": Param((str, os.PathLike, None), "fleet store (folder or postgresql:// URL) to "
                   "record each visit's stiffness per centre and axis and the map's form in "
                   "(docs/store.md)", metavar="STORE"),
}
FILES = {"json": "stiffness.json", "centres": "centres.csv", "deflection": "deflection.csv"}


@dataclass
class StiffnessResult(Result):
    """Stiffness per centre and over the workspace, per machine.

    Attributes
    ----------
    machines : list of dict
        Per machine: ``machine_id``, ``centres`` (per centre and plane: ``centre_mm``,
        ``plane``, ``visit``, ``loads_n``, ``stiffness_n_per_um`` and
        ``stiffness_u_n_per_um`` by the plane's axes, ``compliance_um_per_n`` (2 x 2, the
        plane's axis order), ``compliance_u_um_per_n``), ``map`` (the stiffness map's JSON).
    maps : dict
        machine_id -> ``models.machine.stiffness.StiffnessMap``.
    deflection : DataFrame or None
        With ``at``: its points plus ``dx_um, dy_um[, dz_um]`` and their ``_u_um``.
    source : str
    dates : dict
        (machine_id, visit) -> ISO day of the visit's earliest ``started_at`` (the day a fleet
        store dates its stiffness by); empty when the table has none.
    recorded : pipeline.store.records.Recorded or None
        What ``store`` recorded (the runner sets it).
    """

    machines: list
    maps: dict = field(default_factory=dict, repr=False)
    deflection: object = None  # pandas.DataFrame
    source: str = ""
    parameters: dict = field(default_factory=dict)
    dates: dict = field(default_factory=dict, repr=False)
    recorded: object = None

    def to_dict(self) -> dict:
        """SCHEMA.md section 12: ``{"machines": [{"machine_id", "centres": [...], "map"}]}``;
        with ``at``, ``deflection`` (one record per point)."""
        from features.readings.fileio import clean_nan

        out = {"source": self.source, "machines": self.machines, "notes": list(self.notes)}
        if self.deflection is not None:
            out["deflection"] = self.deflection.to_dict(orient="records")
        return clean_nan(out)

    def centres_frame(self):
        """One row per centre and plane: centre, stiffness and compliance with uncertainties."""
        import pandas as pd

        rows = []
        for m in self.machines:
            for c in m["centres"]:
                row = {"machine_id": m["machine_id"], "plane": c["plane"], "visit": c["visit"],
                       **dict(zip(("centre_x_mm", "centre_y_mm", "centre_z_mm"), c["centre_mm"])),
                       "loads_n": " ".join(f"{v:g}" for v in c["loads_n"])}
                for axis, k in c["stiffness_n_per_um"].items():
                    row[f"k_{axis}_n_per_um"] = k
                    row[f"k_{axis}_u_n_per_um"] = c["stiffness_u_n_per_um"][axis]
                a, b = c["plane"][0], c["plane"][1]
                for (i, j), name in (((0, 0), a + a), ((0, 1), a + b), ((1, 1), b + b)):
                    row[f"c_{name}_um_per_n"] = c["compliance_um_per_n"][i][j]
                    row[f"c_{name}_u_um_per_n"] = c["compliance_u_um_per_n"][i][j]
                rows.append(row)
        return pd.DataFrame(rows)

    def write(self, out) -> dict[str, Path]:
        """``stiffness.json``, ``centres.csv`` and (with ``at``) ``deflection.csv`` under
        ``out``, each written atomically."""
        from features.readings.fileio import atomic_path, write_json

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        saved = self.to_dict()
        for m in saved["machines"]:  # the covariances, so that a saved map predicts again
            m["map"]["covariance"] = {name: cov.tolist() for name, (_, cov)
                                      in self.maps[m["machine_id"]].components.items()}
        self.files = {"json": write_json(out / FILES["json"], saved)}
        frames = [("centres", self.centres_frame())]
        if self.deflection is not None:
            frames.append(("deflection", self.deflection))
        for role, frame in frames:
            with atomic_path(out / FILES[role]) as tmp:
                frame.to_csv(tmp, index=False)
            self.files[role] = out / FILES[role]
        return self.files


def stiffness(data, *, at=None, ram_top_mm: float | None = None, form: str = "auto"
              ) -> StiffnessResult:
    """Stiffness per centre and over the workspace from loaded circular tests (LDBB).

    Parameters
    ----------
    data : str, path-like or DataFrame
        A loaded circular-test table (LDBB), CSV or Parquet (SCHEMA.md section 12,
        docs/stiffness.md): the circle table of section 11 plus ``load_n`` and
        ``centre_x_mm, centre_y_mm, centre_z_mm``; at least two loads per centre.
    at : str, path-like or DataFrame, optional
        Points ``x_mm, y_mm, z_mm, fx_n, fy_n[, fz_n]`` (and ``machine_id`` when the file holds
        several machines), CSV or Parquet, to predict the deflection at [mm, N]
        (``deflection.csv`` in the output folder).
    ram_top_mm : float, optional
        z of the ram's zero extension [mm] (the top of its travel): the cubic map, compliance
        growing with the cube of the ram's extension below this z, is a candidate.
    form : str
        Form of the stiffness map: ``auto`` (chosen by leave-one-centre-out cross-validation)
        or one of ``constant``, ``linear``, ``cubic``, ``quadratic`` (falls back, with a note,
        when the centres cannot carry it).

    Returns
    -------
    StiffnessResult
        Per centre the directional stiffness [N/um] and the plane's compliance [um/N], each
        with its standard uncertainty; per machine the map; the deflections at ``at``.

    Raises
    ------
    InputError
        The file breaks the contract (naming file, row and column); every run at one load; a
        centre run at a single load; ``at`` without a column, with a machine not in the data or
        a force along an axis no circle measured.

    References
    ----------
    Archenti et al., Procedia CIRP 1 (2012) 575-580; Szipka, KTH 2015 (seed 002).
    """
    from features import loaded_circles as flc
    from features.readings.errors import note
    from models.machine import stiffness as st

    file = data if isinstance(data, (str, os.PathLike)) else None
    frame = flc.read_loaded_circles(data)
    items = flc.centres(frame)
    flc.check_loads(items, file)
    notes, machines, maps = [], [], {}
    for machine_id in dict.fromkeys(c.machine_id for c in items):
        mine = [c for c in items if c.machine_id == machine_id]
        found = [(c, st.centre_compliance(c.plane, c.runs)) for c in mine]
        centres_json = [_centre_json(c, pc) for c, pc in found]
        positions, values = st.map_values((c.centre_mm, pc) for c, pc in found)
        stiffness_map, map_notes = st.choose_map(positions, values, ram_top_mm, form)
        notes += [f"machine {machine_id!r}: {n}" for n in map_notes]
        maps[machine_id] = stiffness_map
        machines.append({"machine_id": machine_id, "centres": centres_json,
                         "map": stiffness_map.to_dict()})
    deflection = None
    if at is not None:
        deflection, at_notes = _deflection(at, maps, items)
        notes += at_notes
    for text in notes:
        note(text)
    return StiffnessResult(machines=machines, maps=maps, deflection=deflection,
                           source=str(data) if file is not None else "<frame>",
                           parameters={"ram_top_mm": ram_top_mm, "form": form}, notes=notes,
                           dates=_visit_days(frame))


def _visit_days(frame) -> dict:
    """(machine_id, visit) -> the ISO day of the visit's earliest ``started_at``."""
    if "started_at" not in frame or frame["started_at"].isna().all():
        return {}
    first = frame.groupby(["machine_id", "visit"], sort=False)["started_at"].min().dropna()
    return {(str(m), str(v)): t.date().isoformat() for (m, v), t in first.items()}


def _centre_json(centre, pc) -> dict:
    import numpy as np

    cov = pc.covariance
    u = np.sqrt(np.diag(cov))
    return {"centre_mm": [float(v) for v in centre.centre_mm], "plane": pc.plane,
            "visit": centre.visit, "loads_n": centre.loads_n,
            "stiffness_n_per_um": {a: float(v) for a, v in pc.stiffness_n_per_um.items()},
            "stiffness_u_n_per_um": pc.stiffness_u_n_per_um,
            "compliance_um_per_n": pc.compliance_um_per_n.tolist(),
            "compliance_u_um_per_n": [[float(u[0]), float(u[1])], [float(u[1]), float(u[2])]],
            "rms_residual_um_per_n": pc.rms_residual_um_per_n}


def _deflection(at, maps: dict, items) -> tuple:
    """The points of ``at`` with their predicted deflection and notes on extrapolation."""
    import numpy as np

    from features import loaded_circles as flc
    from features.readings.errors import InputError
    from models.machine import stiffness as st

    points = flc.read_points(at)
    where = ({"file": at} if isinstance(at, (str, os.PathLike)) else {"parameter": "at"})
    if "machine_id" in points:
        machine = points["machine_id"].astype(str).str.strip()
        unknown = sorted(set(machine) - set(maps))
        if unknown:
            raise InputError(f"machine {unknown[0]!r} has no loaded circles in the data; "
                             f"expected one of {', '.join(maps)}", column="machine_id", **where)
    elif len(maps) > 1:
        raise InputError(f"the data hold machines {', '.join(maps)}: give each point its "
                         "machine_id", column="machine_id", **where)
    else:
        machine = np.full(len(points), next(iter(maps)))
    force_cols = ["fx_n", "fy_n", "fz_n"] if "fz_n" in points else ["fx_n", "fy_n"]
    xyz = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    force = np.zeros((len(points), 3))
    force[:, :len(force_cols)] = points[force_cols].to_numpy(float)
    d = np.full((len(points), 3), np.nan)
    u = np.full((len(points), 3), np.nan)
    notes = []
    for machine_id, stiffness_map in maps.items():
        mask = np.asarray(machine == machine_id)
        if not mask.any():
            continue
        d[mask], u[mask] = st.deflection_um(stiffness_map, xyz[mask], force[mask])
        measured = {a for name in stiffness_map.components for a in name}
        for j, axis in enumerate(st.AXES[:len(force_cols)]):
            if axis not in measured and np.any(force[mask, j] != 0):
                raise InputError(f"forces along {axis} need loaded circles in a plane holding "
                                 f"{axis}; machine {machine_id!r} has none",
                                 column=force_cols[j], **where)
        centre_xyz = np.array([c.centre_mm for c in items if c.machine_id == machine_id])
        lo, hi = centre_xyz.min(axis=0), centre_xyz.max(axis=0)
        outside = (xyz[mask] < lo - 1e-9) | (xyz[mask] > hi + 1e-9)
        if outside.any():
            notes.append(f"machine {machine_id!r}: {int(outside.any(axis=1).sum())} of the points "
                         "lie outside the box of the measured centres: their deflection is "
                         "extrapolated by the map")
    out = points.copy()
    for j, axis in enumerate("xyz"[:len(force_cols)]):
        out[f"d{axis}_um"] = d[:, j]
        out[f"d{axis}_u_um"] = u[:, j]
    return out, notes
