"""Closed loop in the twin: re-measure the twin with the written files applied by its controller.

The twin's readings folder holds ``parameters.json`` (configuration and seed). The same machines
(same seed) are measured again in a new session (new run conditions and noise, so the
compensation is not judged on the noise it was made from), once without and once with the
controller models parsed from the *written files* (``models.physics.controller.load``); both
runs share that session's conditions and noise, so their difference is the compensation alone.
The ISO 230-2 figures of the tests the compensation was made from (latest visit, linear tests)
are compared before and after.
An axis passes when neither B nor E grows beyond the noise (a sign error doubles them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from pipeline.compensation.profile import latest_visit

FIGURES = ("A", "E", "M", "R", "B", "B_mean")
SESSION = 1  # seed of the re-measuring session


def twin_parameters(data_path) -> dict:
    """``parameters.json`` written by ``backlash simulate`` beside the readings."""
    path = Path(data_path).parent / "parameters.json"
    if not path.is_file():
        raise InputError("needs twin data: no parameters.json beside the readings (written by "
                         "simulate)", file=data_path, parameter="verify")
    try:
        parameters = json.loads(path.read_text(encoding="utf-8"))
        return {"config": parameters["config"], "seed": int(parameters["seed"])}
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise InputError(f"not a twin parameters file: {err}", file=path) from None


def uncompensated(data_path, active: dict | None = None) -> pd.DataFrame:
    """The twin's readings re-simulated as the data were measured (the 'before' of every
    check): without compensation, or with the ``active`` one ((machine, axis) ->
    ``Compensation``) applied."""
    from models.physics.campaign import simulate

    params = twin_parameters(data_path)
    return simulate(params["config"], params["seed"], compensation=active,
                    session_seed=SESSION).readings


def closed_loop(data_path, profiles, controller: str, written: dict,
                before: pd.DataFrame | None = None, sign: str | None = None) -> list[dict]:
    """ISO figures before and after per machine axis; ``written`` maps (machine, axis) to the
    writer's ``files``, read with the table ``sign`` convention (default the controller's).
    Returns one dict per axis with ``before``/``after`` per-target tables."""
    from models.physics.campaign import simulate
    from pipeline.compensation import read

    params = twin_parameters(data_path)
    comps = {key: read(controller, files, sign) for key, files in written.items()}
    before = uncompensated(data_path) if before is None else before
    after = simulate(params["config"], params["seed"], compensation=comps,
                     session_seed=SESSION).readings
    results = []
    for profile in profiles:
        key = (profile.machine_id, profile.axis)
        result = {"machine_id": profile.machine_id, "axis": profile.axis}
        for name, readings in (("before", before), ("after", after)):
            tests = _tests_used(readings, *key)
            result[name], result[f"{name}_targets"] = _figures(tests)
        noise = result["before"]["noise"]
        result["passed"] = bool(
            result["after"]["B"] <= max(result["before"]["B"], noise)
            and result["after"]["E"] <= max(result["before"]["E"], noise))
        result["ratio_B"] = _ratio(result["after"]["B"], result["before"]["B"])
        result["ratio_E"] = _ratio(result["after"]["E"], result["before"]["E"])
        results.append(result)
    return results


def _ratio(after: float, before: float) -> float:
    return float(after / before) if before > 0 else float("nan")


def _tests_used(readings: pd.DataFrame, machine: str, axis: str) -> pd.DataFrame:
    part = readings[(readings["machine_id"] == machine) & (readings["axis"] == axis)]
    part = part[part["visit"] == latest_visit(part)]
    if "linear" in set(part["method"]):
        part = part[part["method"] == "linear"]
    return part


def _figures(readings: pd.DataFrame) -> tuple[dict, pd.DataFrame]:
    """Mean over the tests of each ISO axis figure [um], the noise level (2 x median s) and the
    per-target means pooled over the tests (for the chart)."""
    from features import iso230

    per = iso230.per_target(readings)
    axis = iso230.axis_figures(readings, per)
    figures = {k: float(axis[k].mean()) for k in FIGURES}
    figures["tests"] = len(axis)
    figures["noise"] = float(2 * np.nanmedian(np.r_[per["s_up"], per["s_down"]]))
    pooled = per.groupby("target")[["mean_up", "mean_down", "s_up", "s_down", "B_i"]].mean()
    return figures, pooled.reset_index()
