"""Volumetric compensation replicated: the seed paper's traditional and Abbe-aware models on
the machine twin, judged on the four body diagonals.

>>> import backlash as bl
>>> result = bl.volumetric(seed=0)                                   # doctest: +SKIP
>>> result.diagonals["PPP"]                                          # doctest: +SKIP
{'before_um': 44.0..., 'traditional_um': -4.4..., 'abbe_um': 1.6...}

The twin (``models.physics.machine.paper_machine``) is the paper's XHK714 with its travels and
errors sized on its Figure 5; six-channel laser tests off the tool point identify the 21
errors (``models.machine.volumetric``) twice, once taking the optics to be at the tool point
(traditional) and once at their true offset (Abbe-aware); the control compensates with each,
and the four ISO 230-6 body diagonals are measured before and after [Chen2022]_.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path

from pipeline.results import Result
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import SEED, Param

# The seed paper's Table 1 [um]: the extreme deviation before and after compensation
PAPER_TABLE1 = {
    "diagonals": {"NPP": {"before_um": -62.5, "traditional_um": -17.4,
                          "before_abbe_um": -65.5, "abbe_um": 9.4},
                  "NPN": {"before_um": -66.7, "traditional_um": -18.7,
                          "before_abbe_um": -78.3, "abbe_um": -6.6},
                  "PPP": {"before_um": -77.2, "traditional_um": -7.7,
                          "before_abbe_um": -76.5, "abbe_um": -4.2},
                  "PPN": {"before_um": -74.6, "traditional_um": -14.3,
                          "before_abbe_um": -79.7, "abbe_um": -7.1}},
    "axes": {"X": {"before_um": 65.6, "traditional_um": -15.3,
                   "before_abbe_um": -62.4, "abbe_um": -16.7},
             "Y": {"before_um": 24.1, "traditional_um": -12.8,
                   "before_abbe_um": 26.1, "abbe_um": -14.2},
             "Z": {"before_um": -77.2, "traditional_um": -19.2,
                   "before_abbe_um": -63.8, "abbe_um": -16.5}},
}
CIRCLE_PLANES = ("XY", "YZ", "ZX")


# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["--targets", "5", "--seed", "3"],
    {"targets": 5, "seed": 3},
)

PARAMETERS = {
    "seed": Param(SEED),
    "targets": Param((Interval(Integral, 5, 101, closed="both"),)),
    "radius_mm": Param((Interval(Real, 0, 500, closed="right"),), metavar="MM"),
    "path": Param((str, os.PathLike, "pandas.DataFrame", None), metavar="PATH.csv"),
    "stiffness": Param((str, os.PathLike, None), metavar="FILE"),
    "out": Param((str, os.PathLike, None), "folder for volumetric.json, diagonals.csv (every "
                 "reading), circles.csv (ISO 230-4, SCHEMA section 11) and, with --path, "
                 "path.csv", output="folder"),
}
# The parts of the error along a path, each from its own model (models.machine.path_error)
PARTS = ("geometric", "backlash", "load")


@dataclass
class VolumetricResult(Result):
    """The paper's comparison replicated on the twin.

    Attributes
    ----------
    diagonals : dict
        Body diagonal (PPP, NPP, PPN, NPN) -> ``before_um``, ``traditional_um``, ``abbe_um``:
        the deviation of largest magnitude along it, with its sign [um].
    axes : dict
        Axis -> the same for its positioning at the tool point [um].
    identification : dict
        Model -> per axis and channel the largest |identified - true| error function over the
        travel [um, urad], and the squareness errors [urad].
    readings : DataFrame
        Every diagonal reading: ``diagonal``, ``stage``, ``target``, ``distance_mm``,
        ``deviation_um``.
    circles : DataFrame
        ISO 230-4 circles of the same twin in XY, YZ and ZX, CW and CCW (SCHEMA section 11).
    seed : int
    path : DataFrame or None
        With ``path``: its columns plus, per axis a (x, y, z), ``geometric_a_um``,
        ``backlash_a_um``, ``load_a_um``, ``load_a_u_um`` and ``total_a_um``.
    path_summary : dict or None
        With ``path``: the models used (play per axis, the stiffness source and map form),
        the largest magnitude of each part and of the total, and how far each part is from
        the twin's own (``error_vs_twin_um``).
    """

    diagonals: dict
    axes: dict
    identification: dict
    readings: object  # pandas.DataFrame
    circles: object  # pandas.DataFrame
    seed: int = 0
    parameters: dict = field(default_factory=dict)
    path: object = None  # pandas.DataFrame: the path's points and the error's parts
    path_summary: dict | None = None

    @property
    def finding(self) -> dict:
        """Per diagonal: does the Abbe-aware model leave less than the traditional one?"""
        return {name: abs(v["abbe_um"]) < abs(v["traditional_um"])
                for name, v in self.diagonals.items()}

    def write(self, out) -> dict[str, Path]:
        """``volumetric.json``, ``diagonals.csv`` (every reading) and ``circles.csv`` under
        ``out``."""
        from features.readings.fileio import atomic_path, write_json

        out = Path(out)
        self.files = {"json": write_json(out / "volumetric.json", self.to_dict())}
        frames = [("diagonals", self.readings), ("circles", self.circles)]
        if self.path is not None:
            frames.append(("path", self.path))
        for role, frame in frames:
            path = out / f"{role}.csv"
            with atomic_path(path) as tmp:
                frame.to_csv(tmp, index=False)
            self.files[role] = path
        return self.files

    def to_dict(self) -> dict:
        out = {"seed": self.seed, "diagonals": self.diagonals, "axes": self.axes,
               "finding": {"abbe_below_traditional": self.finding,
                           "holds": all(self.finding.values())},
               "identification": self.identification, "paper": PAPER_TABLE1,
               "notes": list(self.notes)}
        if self.path is not None:
            from features.readings.fileio import clean_nan

            out["path"] = clean_nan({**self.path_summary,
                                     "points": self.path.to_dict(orient="records")})
        return out


def volumetric(*, seed: int = 0, targets: int = 11, radius_mm: float = 150.0, path=None,
               stiffness=None) -> VolumetricResult:
    """Compensate the twin's volumetric error with the traditional and the Abbe-aware model.

    Parameters
    ----------
    seed : int
        Random seed of the measurement noise: the same seed gives the same numbers.
    targets : int
        Targets along each axis and each diagonal, 5 to 101 (the paper used 11).
    radius_mm : float
        Radius of the circular tests written beside (``circles.csv``) [mm].
    path : str, path-like or DataFrame, optional
        A tool path with its quasi-static forces, ``x_mm, y_mm, z_mm, fx_n, fy_n[, fz_n]`` [mm,
        N], CSV or Parquet, in the order the tool runs it: the error at each point
        (``path.csv``) in three parts, each from the model the twin's tests gave: geometric
        (the Abbe-aware identification), backlash (the play the circles' diagnosis found, by
        the direction each axis last moved) and load (the stiffness map of loaded circles)
        [Szipka2015]_.
    stiffness : str or path-like, optional
        Where the load part's stiffness comes from: a loaded-circle table (LDBB, CSV or
        Parquet, SCHEMA.md section 12; its map's cubic ram term extends below the top of the
        twin's Z travel) or a ``stiffness.json`` written by ``backlash stiffness --out``;
        default: the twin's own loaded circles (27 centres, 100, 300 and 500 N). Used only
        with a tool path.

    Returns
    -------
    VolumetricResult
        The extreme body-diagonal and axis deviations before and after each compensation
        [um], how well each model identified the errors, every diagonal reading, and circles.

    References
    ----------
    .. [Chen2022] G. Chen et al. (seed 001), Table 1; ISO 230-6 (body diagonals).
    .. [Szipka2015] K. Szipka, KTH 2015 (seed 002): the error under quasi-static load along a
       tool path, from the geometric model and the stiffness.

    Raises
    ------
    InputError
        ``path`` breaks its contract; ``stiffness`` without ``path``, or a file that is
        neither a loaded-circle table nor a saved stiffness result.
    """
    if stiffness is not None and path is None:
        from features.readings.errors import InputError

        raise InputError("applies to a tool path: give path too (the load-induced error "
                         "along it)", parameter="stiffness")
    points = None
    if path is not None:  # read before the work: a bad path is refused at once
        from features.loaded_circles import read_points

        points = read_points(path, "path")
    import pandas as pd

    from models.machine import volumetric as vol
    from models.physics import machine as twin

    machine = twin.paper_machine()
    comparison = vol.compare(machine, vol.Setup(targets=targets), seed)
    circles = pd.concat([twin.circle_test(machine, plane=p, direction=d, radius_mm=radius_mm)
                         for p in CIRCLE_PLANES for d in ("CCW", "CW")], ignore_index=True)
    result = VolumetricResult(
        diagonals=comparison.extremes("diagonals"), axes=comparison.extremes("axes"),
        identification={n: vol.identification_error(g, machine.geometry)
                         for n, g in comparison.models.items()},
        readings=comparison.diagonals, circles=circles, seed=seed,
        parameters={"seed": seed, "targets": targets, "radius_mm": radius_mm})
    missed = [n for n, ok in result.finding.items() if not ok]
    if missed:
        result.notes.append(f"the Abbe-aware model did not leave less than the traditional one "
                            f"on {', '.join(missed)}")
    if points is not None:
        result.path, result.path_summary, notes = _path_error(
            machine, comparison.models["abbe"], circles, points, stiffness, seed)
        result.notes.extend(notes)
        result.parameters["stiffness"] = None if stiffness is None else str(stiffness)
    return result


def _path_error(machine, geometry, circles, points, stiffness, seed: int):
    """The path's points with the three parts of the error, the summary and notes."""
    import numpy as np

    from models.machine import circle as mc
    from models.machine import path_error as pe
    from models.machine import stiffness as st
    from models.physics import machine as twin

    xyz = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    force = np.zeros((len(points), 3))
    cols = [c for c in ("fx_n", "fy_n", "fz_n") if c in points]
    force[:, :len(cols)] = points[cols].to_numpy(float)
    # backlash: the play each plane's circles (CW and CCW) found, per axis weighted by 1/u^2
    found = []
    for plane, part in circles.groupby("plane", sort=False):
        runs = [(d, r["angle_deg"].to_numpy(), r["deviation_um"].to_numpy())
                for d, r in part.groupby("direction", sort=False)]
        d = mc.diagnose(runs, float(part["radius_mm"].iloc[0]),
                        float(part["feed_mm_min"].iloc[0]))
        first, second = plane[0], plane[1]
        found += [(first, d.value["backlash_1"], d.u["backlash_1"]),
                  (second, d.value["backlash_2"], d.u["backlash_2"])]
    play, play_u = pe.combined_play_um(found)
    stiffness_map, source, notes = _stiffness_map(machine, stiffness, seed)
    parts = {"geometric": twin.tool_error_um(geometry, xyz, machine.tool_mm),
             "backlash": pe.backlash_error_um(xyz, play)}
    parts["load"], load_u = st.deflection_um(stiffness_map, xyz, force)
    unknown = [a for j, a in enumerate(twin.AXES) if np.isnan(parts["load"][:, j]).any()]
    if unknown:
        notes.append(f"the loaded circles hold no compliance coupling {', '.join(unknown)} to "
                     "the path's forces: the load-induced error along it is left empty and the "
                     "total holds the geometric and backlash parts there")
    out = points.copy()
    for j, axis in enumerate("xyz"):
        for name in PARTS:
            out[f"{name}_{axis}_um"] = parts[name][:, j]
        out[f"load_{axis}_u_um"] = load_u[:, j]
        out[f"total_{axis}_um"] = sum(np.nan_to_num(parts[name][:, j]) for name in PARTS)
    # the twin's own, to say how far each model is from it
    truth = {"geometric": twin.tool_error_um(machine.geometry, xyz, machine.tool_mm),
             "backlash": pe.backlash_error_um(xyz, {a: machine.drives[a].backlash_um
                                                    for a in twin.AXES})}
    if stiffness is None:
        from models.physics import loaded_circles as lc

        truth["load"] = lc.paper_stiffness(machine).deflection_um(xyz, force)
    summary = {
        "backlash_um": play, "backlash_u_um": play_u, "stiffness_source": source,
        "stiffness_map": stiffness_map.form,
        "max_abs_um": {name: _largest(v) for name, v in
                       {**parts, "total": sum(np.nan_to_num(v) for v in parts.values())}.items()},
        "error_vs_twin_um": {name: _largest(parts[name] - truth[name]) for name in truth}}
    return out, summary, notes


def _largest(values) -> float | None:
    import numpy as np

    v = np.abs(np.asarray(values, float))
    return float(np.nanmax(v)) if np.isfinite(v).any() else None


def _stiffness_map(machine, stiffness, seed: int):
    """The stiffness map of ``stiffness`` (a loaded-circle table or a saved stiffness.json;
    None: the twin's own loaded circles), its source's name and notes."""
    import json
    from pathlib import Path

    from features import loaded_circles as flc
    from features.readings.errors import InputError
    from models.machine import stiffness as st

    ram_top_mm = float(machine.geometry.travel_mm["Z"][1])
    if stiffness is None:
        from models.physics import loaded_circles as lc

        table, _ = lc.ldbb_campaign(machine, lc.paper_stiffness(machine),
                                    lc.centre_grid(machine), directions=("CCW",), points=72,
                                    noise_um=0.2, seed=seed)
        source, data = "the twin's loaded circles", table
    elif Path(stiffness).suffix.lower() == ".json" or Path(stiffness).is_dir():
        file = Path(stiffness) / "stiffness.json" if Path(stiffness).is_dir() else Path(stiffness)
        try:
            saved = json.loads(file.read_text(encoding="utf-8"))
            machines = saved["machines"]
            if len(machines) != 1:
                raise InputError(f"holds {len(machines)} machines; expected the stiffness of "
                                 "one", file=file)
            return (st.map_from_json(machines[0]["map"]), str(file),
                    [f"stiffness from {file}: map {machines[0]['map']['form']}"])
        except (OSError, ValueError, KeyError, TypeError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError("is not a stiffness result written by backlash stiffness --out "
                             f"(stiffness.json with the map's covariance): {err}",
                             file=file) from None
    else:
        source, data = str(stiffness), stiffness
    items = flc.centres(flc.read_loaded_circles(data, "stiffness"))
    flc.check_loads(items, data if stiffness is not None else None, "stiffness")
    machines = list(dict.fromkeys(c.machine_id for c in items))
    if len(machines) != 1:
        raise InputError(f"holds loaded circles of machines {', '.join(machines)}; expected "
                         "one", file=stiffness)
    found = [(c, st.centre_compliance(c.plane, c.runs)) for c in items]
    positions, values = st.map_values((c.centre_mm, pc) for c, pc in found)
    stiffness_map, notes = st.choose_map(positions, values, ram_top_mm)
    return stiffness_map, source, notes

