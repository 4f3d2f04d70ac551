"""Compensate: controller compensation files from ISO tests or a trained predictor.

Per machine and axis, the error of each approach direction (``pipeline.compensation.profile``)
is written in each chosen controller's own format (``pipeline.compensation.CONTROLLERS``,
conventions and sources in ``docs/controllers.md``). The files are made in memory first and
written by ``CompensationResult.write`` all together or not at all. With ``verify=True`` (twin
readings only) the twin measures its machines again with the files applied by its controller
model, and the ISO 230-2 figures before and after say whether the files help. With ``active``
the tests were measured with that compensation file active, and the new file is the active
file plus the measured residual (``pipeline.compensation.active``).
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from features.readings.errors import InputError, Progress, report
from pipeline.compensation import CONTROLLERS, SIGNS, read, resolve
from pipeline.results import Result
from pipeline.steps.constraints import HasMethods, Interval, StrOptions
from pipeline.steps.parameters import (
    BUDGET,
    FORMAT,
    PROGRESS,
    SELECTION_GROUP,
    Param,
    comma_list,
)
from pipeline.steps.source import readings_of


def controller_help() -> str:
    """The ``--controller`` help, from the controller records."""
    aliases = [f"{a}={c.name}" for c in CONTROLLERS.values() for a in c.aliases]
    return (f"one or more of {', '.join(CONTROLLERS)} (comma-separated), or all; "
            f"aliases {', '.join(aliases)}")


_PATHS = (str, os.PathLike)
# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--machine", "M01", "--axis", "Y", "--controller", "csv", "--out", "{side}/c"],
    {"data": "{two}", "machine": "M01", "axis": "Y", "controller": "csv", "out": "{side}/c"},
)

PARAMETERS = {
    # the readings (as readings() declares them) or a model, described by the docstring
    "data": Param((*_PATHS, "pandas.DataFrame", HasMethods(["predict"])), flag="DATA|MODEL_DIR",
                  reads_readings=True),
    "format": FORMAT,
    # its own help: every controller and alias of the records, which the docstring refers to
    "controller": Param((str, list, tuple), controller_help(), required=True),
    "out": Param((*_PATHS, None), "output folder", required=True, output="folder"),
    "conditions": Param((None, str, dict), metavar="NAME=VALUE,..."),
    "axis": Param((None, str)),
    "machine": Param((None, str, list, tuple), metavar="ID[,ID...]", parse=comma_list,
                     group=SELECTION_GROUP),
    "at_hours": Param((None, Interval(Real, 0, None, closed="left")), metavar="H"),
    "at_date": Param((None, str, dt.date), metavar="YYYY-MM-DD"),
    "spacing": Param((None, Interval(Real, 0, None, closed="neither")), metavar="MM"),
    "reference_mm": Param((None, Interval(Real, None, None, closed="neither"))),
    "fanuc_unit_um": Param((Interval(Real, 0, None, closed="neither"),)),
    "active": Param((None, *_PATHS, list, tuple), metavar="FILE", repeated=True),
    "sign": Param((None, StrOptions(SIGNS))),
    "store": Param((*_PATHS, None), "fleet store (folder or postgresql:// URL, made by "
                   "backlash ingest) to record this compensation in; backlash fleet shows the "
                   "last one", metavar="STORE"),
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
    "verify": Param(("boolean",)),
    "progress": PROGRESS,
}


@dataclass
class CompensationResult(Result):
    """Compensation files for every machine axis and controller, and their closed-loop check.

    Attributes
    ----------
    profiles : list of AxisProfile
        What is compensated, per machine and axis (``pipeline.compensation.profile``).
    controllers : list of str
        The controllers written for.
    written : list of dict
        Per controller and machine axis: ``controller``, ``kind``, ``machine_id``, ``axis``,
        ``files`` (role -> file name, a path under ``out`` once written),
        ``interpolation_error_um`` [um], ``points``, ``spacing_mm`` [mm], ``backlash`` [um],
        ``unconfirmed`` (conventions not confirmed against the controller's manual), ``sign``
        (``"error"``/``"correction"`` of the table values; None when the format fixes it),
        ``per_direction`` (one table per approach direction), ``reversal_left_um``: the
        largest reversal value the files leave at the targets, read back as the controller
        applies them [um]; with ``active``, ``changes``: per target the correction moving +/-
        of the active and the new file and the change [um] (``pipeline.compensation.active``).
    reversal : list of dict
        Per machine axis, the test whether the reversal value varies along the axis by more
        than its uncertainty (``AxisProfile.reversal_variation``).
    active : dict
        (machine_id, axis) -> the active compensation read from ``active``
        (``models.physics.controller.Compensation``); empty without ``active``.
    verification : dict of str to list of dict
        Per controller, the closed-loop results per machine axis
        (``pipeline.compensation.verify.closed_loop``); empty without ``verify``.
    contents : dict of str to bytes
        The files' bytes by file name, as ``write`` writes them.
    """

    profiles: list
    controllers: list[str]
    written: list[dict]
    verification: dict[str, list[dict]] = field(default_factory=dict)
    contents: dict[str, bytes] = field(default_factory=dict, repr=False)
    reversal: list[dict] = field(default_factory=list)
    active: dict = field(default_factory=dict, repr=False)
    out: Path | None = None
    reports: dict[str, Path] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """True unless the closed-loop check found an axis made worse."""
        return all(r["passed"] for results in self.verification.values() for r in results)

    def path(self, name: str) -> Path:
        """Where file ``name`` is (under ``out`` once written)."""
        return Path(name) if self.out is None else self.out / name

    def write(self, out: str | Path) -> dict[str, Path]:
        """Write every controller file into ``out`` (all or none), then the closed-loop
        reports (``verify/<controller>/verify.html``); return the paths by file name."""
        from features.readings.fileio import write_files
        from pipeline.compensation.report import write_report

        out = Path(out)
        self.files = write_files(out, self.contents)
        self.out = out
        for controller, results in self.verification.items():
            self.reports[controller] = write_report(results, controller,
                                                    out / "verify" / controller)
            self.files[f"verify/{controller}/verify.html"] = self.reports[controller]
        return self.files

    def checks(self) -> list[dict]:
        """The closed-loop verdicts per controller and machine axis (figures before and after
        [um], ratios after/before, the report's path once written)."""
        report_of = {c: str(p) for c, p in self.reports.items()}
        return [{"controller": c, "machine_id": r["machine_id"], "axis": r["axis"],
                 "passed": r["passed"], "ratio_B": r["ratio_B"], "ratio_E": r["ratio_E"],
                 "before": r["before"], "after": r["after"], "report": report_of.get(c)}
                for c, results in self.verification.items() for r in results]

    def summary(self) -> list[str]:
        """The human summary, one line each: per machine axis its backlash, reversal test and
        notes; per file set its files, errors [um], residual against U(B) and changes from the
        active file; per closed-loop check its verdict and figures before and after [um]."""
        from features.readings.schema import deviation_unit as unit

        lines = []
        for p, r in zip(self.profiles, self.reversal):
            u = unit(p.axis)
            lines.append(f"{p.machine_id} {p.axis} ({p.source}): reversal compensation "
                         f"{p.backlash:.3f} {u}; {_lost_motion(p, u)}, {len(p.target)} targets")
            if r["direction_dependent"]:
                lines.append(f"  reversal varies along the axis (p {r['p']:.2g}): the scalar "
                             f"leaves up to {r['scalar_leaves_um']:.3f} {u}")
            lines += [f"  note: {note}" for note in p.notes]
        for w in self.written:
            lines += _written_lines(w)
        for c in self.checks():
            u = unit(c["axis"])
            lines.append(f"verify {c['controller']} {c['machine_id']} {c['axis']}: "
                         f"{'passed' if c['passed'] else 'FAILED'}; B {c['before']['B']:.3f} -> "
                         f"{c['after']['B']:.3f} {u}, E {c['before']['E']:.3f} -> "
                         f"{c['after']['E']:.3f} {u} -> {c['report']}")
        return lines

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan({"axes": [_profile_json(p) | {"reversal_variation": r}
                                   for p, r in zip(self.profiles, self.reversal)],
                          "files": [self._written_json(w) for w in self.written],
                          "verify": self.checks()})

    def _written_json(self, w: dict) -> dict:
        out = {k: v for k, v in w.items() if k not in ("files", "changes")}
        out["files"] = {role: str(self.path(name)) for role, name in w["files"].items()}
        if "changes" in w:
            out["changes"] = w["changes"].to_dict(orient="records")
        return out


def _written_lines(w: dict) -> list[str]:
    """The summary lines of one file set (``CompensationResult.summary``), in the axis's
    deviation unit (um, arcsec for a rotary axis)."""
    from features.readings.schema import deviation_unit

    u = deviation_unit(w["axis"])
    files = ", ".join(w["files"].values())
    interp = w["interpolation_error_um"]
    extra = "" if interp is None else f"; interpolation error at targets {interp:.4f} {u}"
    extra += f"; reversal left {w['reversal_left_um']:.3f} {u}"
    unconfirmed = (f"; not confirmed: {'; '.join(w['unconfirmed'])}"
                   if w["unconfirmed"] else "")
    lines = [f"{w['controller']} {w['machine_id']} {w['axis']}: {files}{extra}{unconfirmed}"]
    r = w.get("resolution")
    if r:
        lines.append(f"  residual {r['residual_um']:.3f} um ({r['residual']}) "
                     f"{'beyond' if r['resolvable'] else 'within'} what the measurement can "
                     f"resolve: U(B) {r['U_B_um']:.3f} um")
    if "changes" in w:
        c = w["changes"]
        plus, minus = (c[f"change_{side}_{u}"] for side in ("plus", "minus"))
        lines.append(f"  change from the active file [{u}]: moving + "
                     f"{plus.min():+.3f} to {plus.max():+.3f}, moving - {minus.min():+.3f} to "
                     f"{minus.max():+.3f} ({len(c)} targets)")
    return lines


def compensate(data, *, controller="csv", format: str = "auto", conditions=None,
               at_hours: float | None = None, at_date=None, machine=None,
               axis: str | None = None, spacing: float | None = None,
               reference_mm: float | None = None,
               fanuc_unit_um: float = 1.0, active=None, sign: str | None = None,
               verify: bool = False, uncertainty=None,
               progress: Progress | None = None) -> CompensationResult:
    """Controller compensation files from ISO tests or a trained predictor.

    Parameters
    ----------
    data : path, DataFrame or TrainedModel
        A readings file or a fleet store (a folder or a ``postgresql://`` URL made by
        ``backlash ingest``) of ISO tests (per machine axis, the latest visit's linear tests),
        or a model directory written by ``backlash train`` (its backlash at the conditions
        given over its training target range, no position error; a wear map's per machine axis
        it knows, forecast for the operating hours asked).
    controller : str or list of str, default "csv"
        Names or aliases of ``pipeline.compensation.CONTROLLERS`` (a list or comma-separated),
        or ``"all"``.
    format : str, default "auto"
        Input layout of a readings file.
    conditions : dict or str, optional
        Conditions for a predictor, ``NAME=VALUE,...`` such as
        ``feed_mm_min=500,machine_temp_c=21``; conditions the model needs and is not given are
        its training medians.
    at_hours : float, optional
        A wear map only: the operating hours [h] on the axis's hour counter the table is
        forecast for. Default the middle of the next maintenance interval (the last visit
        plus half the mean interval between visits, in hours), which halves the backlash
        error averaged over the interval against a table frozen at the visit
        (``pipeline.compensation.ahead``).
    at_date : str or datetime.date, optional
        A wear map only: the day (``YYYY-MM-DD``) the table is forecast for, turned into
        operating hours with the axis's usage rate when the model records it (``model.json``
        key ``usage``); otherwise refused, asking for the operating hours instead.
    machine : str or list of str, optional
        Only these machines (comma-separated): their tests of the readings, or their axes of a
        wear map that knows several machine axes.
    axis : str, optional
        Only this axis: its tests of the readings, or its axes of a wear map that knows its
        machine axes; the axis a predictor's table is for (default X).
    spacing : float, optional
        Table spacing of equidistant formats [mm]; default: equidistant targets as they are,
        else a quarter of the smallest target interval rounded down to 1/2/2.5/5 x 10^k.
    reference_mm : float, optional
        Reference point where SINUMERIK, Fanuc and Heidenhain tables are 0 [mm]; default the
        table point nearest 0.
    fanuc_unit_um : float, default 1.0
        Fanuc detection unit [um].
    active : path or list of paths, optional
        The tests were measured with this compensation active (one controller's files for one
        machine axis: its table and/or its parameter file, one path each). The new file is the
        active file plus the measured residual, for that controller only; each file written
        for it reports its change per target (``changes``, also a ``..._changes.csv`` file per
        machine axis and controller in the output folder).
    sign : {"error", "correction"}, optional
        What a positive table value means at this site, for the controllers whose table
        convention is a choice (SINUMERIK, Fanuc, Heidenhain; ``CONTROLLERS[name].sign``);
        default each controller's documented convention. Also how the active files are read.
    verify : bool, default False
        Twin readings only (``parameters.json`` beside the file): re-measure the twin with the
        files applied and compare the ISO figures before and after (``verify.html``); the
        command exits with status 3 when the check finds an axis made worse.
    uncertainty : path, dict or UncertaintyBudget, optional
        The measurement's uncertainty budget, a TOML file as ``iso`` takes it
        (``features.uncertainty``): each file set's residual (the reversal error B after
        compensation when verified, else the largest reversal value the files leave at the
        targets) is within or beyond U(B) at the axis's measuring length and runs per
        direction (``resolution`` of each file set).
    progress : callable, optional
        ``progress(done, total, what)`` during the closed-loop check.

    Returns
    -------
    CompensationResult
        Nothing is written until ``result.write(out)``.
    """
    from features.readings.fileio import MemoryFolder
    from pipeline.compensation.common import Options
    from pipeline.compensation.profile import parse_conditions

    names = resolve(controller)
    fixed = [n for n in names if CONTROLLERS[n].sign is None]
    if sign is not None and fixed:
        from features.readings.errors import note

        note(f"--sign does not apply to {', '.join(fixed)}: the format fixes what their values "
             "mean (positions, named columns or a backlash)")
    conditions = parse_conditions(conditions)
    ahead = {"at_hours": at_hours, "at_date": at_date, "machine": machine, "axis": axis}
    profiles = _profiles(data, format, conditions, ahead, spacing, verify)
    if isinstance(controller, str) and controller.strip().lower() == "all":
        names = _covering(names, profiles)
    if verify:  # refuse before any work
        from pipeline.compensation.verify import twin_parameters

        twin_parameters(data)
    budget = None
    if uncertainty is not None:  # refuse a bad budget before any work
        from features.uncertainty import read_budget

        budget = read_budget(uncertainty)
    options = Options(spacing, reference_mm, fanuc_unit_um, sign)
    comps = _active(active, profiles, names, options) if active is not None else {}
    if comps:
        from pipeline.compensation.active import without

        profiles = [without(p, comps[(p.machine_id, p.axis)]) for p in profiles]
    reversal = [p.reversal_variation() for p in profiles]
    notes = [f"{p.machine_id} {p.axis}: {n}" for p in profiles for n in p.notes]
    notes += _reversal_notes(profiles, reversal, names)
    # The files are made in memory, read back as each controller applies them (and verified
    # on the twin) before anything reaches the disk; ``write`` writes them once, together.
    folder = MemoryFolder()
    written = _write_all(profiles, names, folder, options)
    _read_back(written, profiles, folder, sign, comps)
    verification = _verify(data, profiles, names, written, folder, progress,
                           sign, comps) if verify else {}
    contents = dict(sorted(folder.contents.items()))
    if budget is not None:
        notes += _resolution(written, profiles, verification, budget)
    return CompensationResult(profiles, names, written, verification, contents, reversal,
                              comps, notes=notes)


def _active(active, profiles, names, options) -> dict:
    """The active compensation of the one measured machine axis, read with its controller."""
    from pipeline.compensation.active import read_active

    if any(p.source != "measured" for p in profiles):
        raise InputError("applies to measured tests, not to a predictor", parameter="active")
    if len(names) != 1:
        raise InputError(f"the new file is the active file plus the residual: give its one "
                         f"controller, not {len(names)}", parameter="controller")
    if len(profiles) != 1:
        axes = ", ".join(f"{p.machine_id} {p.axis}" for p in profiles)
        raise InputError(f"active files are of one machine axis; the data hold {axes} (select "
                         "one with --machine and --axis)", parameter="active")
    p = profiles[0]
    return {(p.machine_id, p.axis): read_active(active, names[0], p, options)}


def _covering(names: list[str], profiles) -> list[str]:
    """``controller="all"``: the controllers that compensate every measured axis's kind
    (the scalar formats take linear axes only); a note names those left out."""
    from features.readings.errors import note
    from features.readings.schema import is_rotary

    kinds = {"rotary" if is_rotary(p.axis) else "linear" for p in profiles}
    kept = [n for n in names if kinds <= set(CONTROLLERS[n].axes)]
    left = [n for n in names if n not in kept]
    if left:
        note(f"all: {', '.join(left)} left out (they compensate linear axes only)")
    return kept


def _reversal_notes(profiles, reversal, names) -> list[str]:
    """A note per axis whose reversal value varies along it by more than its uncertainty."""
    from features.readings.errors import note
    from features.readings.schema import deviation_unit

    carry = [n for n in names if CONTROLLERS[n].per_direction]
    scalar = [n for n in names if not CONTROLLERS[n].per_direction]
    notes = []
    for p, r in zip(profiles, reversal):
        if not r["direction_dependent"]:
            continue
        u = deviation_unit(p.axis)
        text = (f"{p.machine_id} {p.axis}: the reversal value varies along the axis by more than "
                f"its uncertainty (B_i {p.reversal.min():.3f} to {p.reversal.max():.3f} {u}, "
                f"chi2 {r['chi2']:.1f} on {r['dof']} dof, p {r['p']:.2g}): a scalar backlash "
                f"cannot compensate it")
        if carry:
            text += f"; a table per direction for {', '.join(carry)}"
        if scalar:
            text += (f"; the scalar {r['scalar_um']:.3f} {u} for {', '.join(scalar)}, which "
                     f"leaves reversal values up to {r['scalar_leaves_um']:.3f} {u}")
        note(text)
        notes.append(text)
    return notes


def _profiles(data, format, conditions, ahead: dict, spacing, verify) -> list:
    """What to compensate: measured profiles from readings, or predicted ones (``ahead``:
    ``at_hours``, ``at_date``, ``machine``, ``axis`` of ``compensate``)."""
    import pandas as pd

    from features.readings.selection import selection
    from pipeline.compensation.profile import measured_profiles
    from pipeline.store import is_store

    is_path = isinstance(data, (str, os.PathLike))
    if (is_path and Path(data).is_dir() and not is_store(data)) or not (is_path or isinstance(data, pd.DataFrame)):
        if verify:
            raise InputError(f"needs twin readings, not a model{' directory' if is_path else ''}",
                             parameter="verify", file=data if is_path else None)
        if is_path:
            from models.serving.registry import load_model

            data = load_model(data)
        return _predicted(data, conditions, spacing, **ahead)
    given = [k for k in ("at_hours", "at_date") if ahead[k] is not None]
    if conditions or given:
        raise InputError(f"applies to a {'wear-map ' if given else ''}model directory, not to "
                         "measured tests", parameter=given[0] if given else "conditions")
    if verify and not is_path:
        raise InputError("needs the twin's readings file (parameters.json beside it), not a "
                         "frame", parameter="verify")
    # measured tests: machine and axis select them, as in every job
    chosen = selection(machine=ahead["machine"], axis=ahead["axis"])
    return measured_profiles(readings_of(data, format, selection=chosen))


def _predicted(model, conditions, spacing, at_hours, at_date, machine, axis) -> list:
    """One profile from a predictor; from a wear map, one per machine axis it knows (those
    selected), each forecast for its operating hours (``pipeline.compensation.ahead``)."""
    from models.wear.wear_map import WearMap
    from pipeline.compensation.ahead import forecast_hours, known_axes, wear_map_of
    from pipeline.compensation.profile import predicted_profile

    if at_hours is not None and at_date is not None:
        raise InputError("give the operating hours or the date, not both", parameter="at_date")
    ahead = "at_hours" if at_hours is not None else "at_date" if at_date is not None else None
    if ahead and "operating_hours" in conditions:
        raise InputError(f"operating_hours is what {ahead} sets; give one of them",
                         parameter="conditions")
    if not isinstance(model.estimator, WearMap):
        if ahead:
            wear_map_of(model, ahead)  # says why not
        if machine is not None:
            raise InputError(f"applies to a wear map that knows its machine axes, not to "
                             f"{model.name!r}", parameter="machine")
        return [predicted_profile(model, conditions, (axis or "X").upper(), spacing)]
    wear = wear_map_of(model, ahead) if ahead else model.estimator
    profiles = []
    for key in known_axes(model, machine, axis):
        given, note = dict(conditions), None
        if wear.can_forecast_ and "operating_hours" not in given:
            hours, note = forecast_hours(model, key, at_hours, at_date)
            if hours is not None:
                given["operating_hours"] = hours
        index = {tuple(map(str, k)): i for i, k in enumerate(wear.axes_)}.get(key)
        travel = wear.axis_range_[index] if wear.pooled_ and index is not None else None
        profile = predicted_profile(model, given, key[1], spacing,
                                    key if wear.pooled_ else None, travel)
        profile.machine_id = key[0]
        if note:
            profile.notes.insert(0, note)
        profiles.append(profile)
    return profiles


def _write_all(profiles, names, folder, options) -> list[dict]:
    """Every controller's files for every profile into ``folder`` (a ``MemoryFolder``); file
    names per role."""
    written = []
    for name in names:
        record = CONTROLLERS[name]
        for profile in profiles:
            result = record.writer(profile, folder, options)
            result.setdefault("sign", record.sign)
            # a writer that chooses per axis (Fanuc: two tables only where the reversal varies)
            result.setdefault("per_direction", record.per_direction)
            result.update(controller=name, kind=record.kind, machine_id=profile.machine_id,
                          axis=profile.axis)
            result["files"] = {role: p.name for role, p in result["files"].items()}
            written.append(result)
    return written


def _read_back(written, profiles, folder, sign, active: dict) -> None:
    """Each file set read back as its controller applies it: the reversal value it leaves
    [um], and with an active file the change per target (also written as a CSV)."""
    import numpy as np

    from features.readings.fileio import write_text
    from pipeline.compensation.active import changes

    by_key = {(p.machine_id, p.axis): p for p in profiles}
    for w in written:
        key = (w["machine_id"], w["axis"])
        p = by_key[key]
        comp = read(w["controller"], {r: folder / f for r, f in w["files"].items()}, sign)
        left = p.reversal + p.scale * (comp.offset_mm(p.target, 1) - comp.offset_mm(p.target, -1))
        w["reversal_left_um"] = round(float(np.max(np.abs(left))), 4)
        if key in active:
            w["changes"] = changes(p, active[key], comp)
            path = folder / f"{p.stem}_{w['controller']}_changes.csv"
            write_text(path, w["changes"].to_csv(index=False, float_format="%.6f"))
            w["files"]["changes"] = path.name


def _resolution(written, profiles, verification, budget) -> list[str]:
    """Each file set's residual against U(B), the expanded uncertainty of the reversal error
    at the axis's measuring length and runs per direction (default the budget's): its
    ``resolution`` ``{"U_B_um", "residual_um", "residual", "resolvable"}`` and a note."""
    from features.readings import schema
    from features.uncertainty import expanded_at_length_um

    by_key = {(p.machine_id, p.axis): p for p in profiles}
    after = {(c, r["machine_id"], r["axis"]): r["after"]["B"]
             for c, results in verification.items() for r in results}
    notes = []
    for w in written:
        p = by_key[(w["machine_id"], w["axis"])]
        length = float(p.target.max() - p.target.min())
        w["resolution"] = None
        if schema.is_rotary(p.axis) or length <= 0:
            notes.append(f"{p.machine_id} {p.axis}: no U(B) for {w['controller']}: "
                         + ("an uncertainty budget holds lengths, not angles"
                            if schema.is_rotary(p.axis) else "one target, no measuring length"))
            continue
        u_b = float(expanded_at_length_um(budget, length, p.cycles or budget.cycles)["B"])
        verified = (w["controller"], p.machine_id, p.axis) in after
        residual = float(after[(w["controller"], p.machine_id, p.axis)] if verified
                         else w["reversal_left_um"])
        what = "B after compensation (verify)" if verified else "reversal left at the targets"
        w["resolution"] = {"U_B_um": round(u_b, 4), "residual_um": round(residual, 4),
                           "residual": what, "resolvable": residual > u_b}
        verdict = "beyond" if residual > u_b else "within"
        notes.append(f"{p.machine_id} {p.axis} {w['controller']}: residual {residual:.3f} um "
                     f"({what}) {verdict} what the measurement can resolve (U(B) {u_b:.3f} um "
                     f"at {length:g} mm)")
    return notes


def _verify(data, profiles, names, written, folder, progress, sign=None,
            active=None) -> dict[str, list[dict]]:
    """Closed loop per controller, on the files as made (read back from ``folder``);
    'before' is the twin with the ``active`` compensation, if any, applied."""
    from pipeline.compensation.verify import closed_loop, uncompensated

    report(progress, 0, len(names) + 1, "twin without compensation" if not active else
           "twin with the active compensation")
    before = uncompensated(data, active or None)
    verification = {}
    for i, name in enumerate(names, start=1):
        report(progress, i, len(names) + 1, name)
        files = {(w["machine_id"], w["axis"]): {role: folder / f for role, f in w["files"].items()}
                 for w in written if w["controller"] == name}
        verification[name] = closed_loop(data, profiles, name, files, before, sign)
    report(progress, len(names) + 1, len(names) + 1, "done")
    return verification


def _lost_motion(p, unit: str) -> str:
    """The axis's lost motion beside the scalar (one definition: docs/backlash.md)."""
    if p.source == "predicted":
        return f"the predicted lost motion {p.backlash:.3f} {unit}"
    if p.lost_motion_um is None:
        return "lost motion unknown"
    return f"the axis's lost motion {p.lost_motion_um:.3f} {unit} (docs/backlash.md)"


def _profile_json(p) -> dict:
    return {"machine_id": p.machine_id, "axis": p.axis, "source": p.source,
            "reversal_compensation_um": p.backlash,
            "lost_motion_um": p.backlash if p.source == "predicted" else p.lost_motion_um,
            "targets_mm": p.target.tolist(),
            "mean_up_um": p.mean_up.tolist(), "mean_down_um": p.mean_down.tolist(),
            "reversal_um": p.reversal.tolist(), "at_hours": p.at_hours, "notes": p.notes}


