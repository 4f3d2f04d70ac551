"""Compensate: controller compensation files from ISO tests or a trained predictor.

Per machine and axis, the error of each approach direction (``pipeline.compensation.profile``)
is written in each chosen controller's own format (``pipeline.compensation.CONTROLLERS``,
conventions and sources in ``docs/controllers.md``). The files are made in memory first and
written by ``CompensationResult.write`` all together or not at all. With ``verify=True`` (twin
readings only) the twin measures its machines again with the files applied by its controller
model, and the ISO 230-2 figures before and after say whether the files help.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from features.readings.errors import InputError, Progress, report
from pipeline.compensation import CONTROLLERS, resolve
from pipeline.results import Result
from pipeline.workflows import Constraints, Workflow, check_params, readings_of


def _parameters() -> dict:
    """The constraints of ``compensate``'s parameters (scikit-learn's constraint language),
    built on first use: importing scikit-learn and pandas would slow every command's start."""
    import pandas as pd
    from sklearn.utils._param_validation import HasMethods, Interval

    return {
        "data": [str, os.PathLike, pd.DataFrame, HasMethods(["predict"])],
        "controller": [str, list, tuple],
        "format": [str],
        "conditions": [None, str, dict],
        "axis": [str],
        "spacing": [None, Interval(Real, 0, None, closed="neither")],
        "reference_mm": [None, Interval(Real, None, None, closed="neither")],
        "fanuc_unit_um": [Interval(Real, 0, None, closed="neither")],
        "verify": ["boolean"],
        "progress": [None, callable],
    }


PARAMETERS = Constraints(_parameters)


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
        ``unconfirmed`` (conventions not confirmed against the controller's manual).
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
        from pipeline.compensation.report import write_report

        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
        try:
            for name, content in self.contents.items():
                (tmp / name).write_bytes(content)
            out.mkdir(exist_ok=True)
            for name in self.contents:
                os.replace(tmp / name, out / name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        self.out = out
        self.files = {name: out / name for name in self.contents}
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

    def to_json(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan({"axes": [_profile_json(p) for p in self.profiles],
                          "files": [self._written_json(w) for w in self.written],
                          "verify": self.checks()})

    def _written_json(self, w: dict) -> dict:
        out = {k: v for k, v in w.items() if k != "files"}
        out["files"] = {role: str(self.path(name)) for role, name in w["files"].items()}
        return out


def compensate(data, *, controller="csv", format: str = "auto", conditions=None,
               axis: str = "X", spacing: float | None = None, reference_mm: float | None = None,
               fanuc_unit_um: float = 1.0, verify: bool = False,
               progress: Progress | None = None) -> CompensationResult:
    """Controller compensation files from ISO tests or a trained predictor.

    Parameters
    ----------
    data : path, DataFrame or TrainedModel
        A readings file, fleet store or frame (ISO tests: per machine axis, the latest
        visit's linear tests), or a model directory written by ``train`` or a loaded model (its backlash at
        ``conditions`` over its training target range, no position error).
    controller : str or list of str, default "csv"
        Names or aliases of ``pipeline.compensation.CONTROLLERS`` (a list or comma-separated),
        or ``"all"``.
    format : str, default "auto"
        Input layout of a readings file.
    conditions : dict or str, optional
        Conditions for a predictor (``{"feed_mm_min": 500}`` or ``"feed_mm_min=500"``);
        conditions the model needs and is not given are its training medians.
    axis : str, default "X"
        Axis name for a predictor.
    spacing : float, optional
        Table spacing of equidistant formats [mm]; default: equidistant targets as they are,
        else a quarter of the smallest target interval rounded down to 1/2/2.5/5 x 10^k.
    reference_mm : float, optional
        Reference point where SINUMERIK, Fanuc and Heidenhain tables are 0 [mm]; default the
        table point nearest 0.
    fanuc_unit_um : float, default 1.0
        Fanuc detection unit [um].
    verify : bool, default False
        Twin readings only (``parameters.json`` beside the file): re-measure the twin with the
        files applied and compare the ISO figures before and after.
    progress : callable, optional
        ``progress(done, total, what)`` during the closed-loop check.

    Returns
    -------
    CompensationResult
        Nothing is written until ``result.write(out)``.
    """
    check_params(_parameters(), {"data": data, "controller": controller, "format": format,
                              "conditions": conditions, "axis": axis, "spacing": spacing,
                              "reference_mm": reference_mm, "fanuc_unit_um": fanuc_unit_um,
                              "verify": verify, "progress": progress}, "compensate")
    from pipeline.compensation.common import Options
    from pipeline.compensation.profile import parse_conditions

    names = resolve(controller)
    conditions = parse_conditions(conditions)
    profiles = _profiles(data, format, conditions, axis.upper(), spacing, verify)
    if verify:  # refuse before any work
        from pipeline.compensation.verify import twin_parameters

        twin_parameters(data)
    options = Options(spacing, reference_mm, fanuc_unit_um)
    with tempfile.TemporaryDirectory(prefix="backlash-compensation-") as folder:
        written = _write_all(profiles, names, Path(folder), options)
        verification = _verify(data, profiles, names, written, Path(folder), progress) \
            if verify else {}
        contents = {p.name: p.read_bytes() for p in sorted(Path(folder).iterdir())}
    notes = [f"{p.machine_id} {p.axis}: {n}" for p in profiles for n in p.notes]
    return CompensationResult(profiles, names, written, verification, contents, notes=notes)


def _profiles(data, format, conditions, axis, spacing, verify) -> list:
    """What to compensate: measured profiles from readings, or one predicted profile."""
    import pandas as pd

    from pipeline.compensation.profile import measured_profiles, predicted_profile
    from pipeline.store import is_store

    is_path = isinstance(data, (str, os.PathLike))
    if (is_path and Path(data).is_dir() and not is_store(data)) or not (is_path or isinstance(data, pd.DataFrame)):
        if verify:
            raise InputError(f"needs twin readings, not a model{' directory' if is_path else ''}",
                             parameter="verify", file=data if is_path else None)
        if is_path:
            from models.registry import load_model

            data = load_model(data)
        return [predicted_profile(data, conditions, axis, spacing)]
    if conditions:
        raise InputError("applies to a model directory, not to measured tests",
                         parameter="conditions")
    if verify and not is_path:
        raise InputError("needs the twin's readings file (parameters.json beside it), not a "
                         "frame", parameter="verify")
    return measured_profiles(readings_of(data, format))


def _write_all(profiles, names, folder: Path, options) -> list[dict]:
    """Every controller's files for every profile into ``folder``; file names per role."""
    written = []
    for name in names:
        record = CONTROLLERS[name]
        for profile in profiles:
            result = record.writer(profile, folder, options)
            result.update(controller=name, kind=record.kind, machine_id=profile.machine_id,
                          axis=profile.axis)
            result["files"] = {role: Path(p).name for role, p in result["files"].items()}
            written.append(result)
    return written


def _verify(data, profiles, names, written, folder: Path, progress) -> dict[str, list[dict]]:
    """Closed loop per controller, on the files as written (read back from ``folder``)."""
    from pipeline.compensation.verify import closed_loop, uncompensated

    report(progress, 0, len(names) + 1, "twin without compensation")
    before = uncompensated(data)
    verification = {}
    for i, name in enumerate(names, start=1):
        report(progress, i, len(names) + 1, name)
        files = {(w["machine_id"], w["axis"]): {role: folder / f for role, f in w["files"].items()}
                 for w in written if w["controller"] == name}
        verification[name] = closed_loop(data, profiles, name, files, before)
    report(progress, len(names) + 1, len(names) + 1, "done")
    return verification


def _profile_json(p) -> dict:
    return {"machine_id": p.machine_id, "axis": p.axis, "source": p.source,
            "reversal_compensation_um": p.backlash, "targets_mm": p.target.tolist(),
            "mean_up_um": p.mean_up.tolist(), "mean_down_um": p.mean_down.tolist(),
            "reversal_um": p.reversal.tolist(), "notes": p.notes}


_LABELS = ", ".join(c.label for c in CONTROLLERS.values())
WORKFLOW = Workflow(
    name="compensate", function=compensate,
    summary=(f"Write controller compensation files ({_LABELS}) from ISO tests or a predictor; "
             "optionally re-measure the twin with them applied."),
    inputs=("data",))
