"""The one runner (``pipeline.runner``): the CLI, experiment files and ``bl.<job>`` run a job
the same way, with the same parameters meaning the same, and give the same result."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import pytest

import backlash as bl
from features.readings.errors import InputError
from features.readings.fileio import dumps
from pipeline.cli import main
from pipeline.workflows import NAMES

ROOT = Path(__file__).resolve().parents[1]
TWIN = ROOT / "experiments" / "data" / "twin" / "readings.csv"
FORBIDDEN = re.compile(r"mlflow|optuna|pipeline\.tracking|pipeline\.store|pipeline\.background_run"
                       r"|pipeline\.model_tracking|from pipeline import (tracking|store|"
                       r"background_run|model_tracking)")


def test_no_command_module_imports_tracking_store_or_the_background_runner():
    """Commands parse, call the runner and print: the work around the job is the runner's."""
    offending = [f"{path.name}: {line.strip()}"
                 for path in sorted((ROOT / "pipeline" / "commands").glob("*.py"))
                 for line in path.read_text().splitlines()
                 if re.match(r"\s*(from|import)\s", line) and FORBIDDEN.search(line)]
    assert offending == []


@pytest.fixture(scope="module")
def two_axes(tmp_path_factory) -> Path:
    """A small campaign of two axes of one machine: the twin's M02 X tests relabelled as
    M01 Y (different tests, so selecting the axis changes the answer)."""
    frame = bl.simulate(preset="compensation").readings.astype({"test_id": str})
    second = frame["machine_id"] == "M02"
    frame.loc[second, "test_id"] = frame.loc[second, "test_id"].str.replace("M02-X", "M01-Y")
    frame.loc[second, ["machine_id", "axis"]] = ["M01", "Y"]
    path = tmp_path_factory.mktemp("two-axes") / "two.csv"
    bl.write(frame, path)
    return path


def cli_json(args: list[str], capsys, code: int = 0) -> dict:
    capsys.readouterr()
    assert main(args) == code, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def py_json(job: str, *args, **params) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = getattr(bl, job.replace("-", "_"))(*args, **params)
    return json.loads(dumps(result.to_json()))


def without_paths(value):
    """The JSON with the files' folders dropped (the CLI writes into --out, Python into
    nothing or its own ``out``)."""
    if isinstance(value, dict):
        return {k: without_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [without_paths(v) for v in value]
    if isinstance(value, str) and ("/" in value or "\\" in value):
        return Path(value).name
    return value


def test_compensate_selects_the_machine_and_axis_from_python_as_from_the_cli(two_axes, tmp_path,
                                                                             capsys):
    """``backlash compensate DATA --machine M01 --axis Y`` equals ``bl.compensate(DATA,
    machine="M01", axis="Y")``; Y's tests, not X's (Python used to refuse the machine and
    return X for the axis)."""
    cli = cli_json(["compensate", str(two_axes), "--machine", "M01", "--axis", "Y",
                    "--controller", "csv", "--out", str(tmp_path / "c"), "--json"], capsys)
    python = py_json("compensate", str(two_axes), machine="M01", axis="Y", controller="csv")
    assert without_paths(cli) == without_paths(python)
    assert [(a["machine_id"], a["axis"]) for a in python["axes"]] == [("M01", "Y")]
    only_y = py_json("compensate", str(two_axes), axis="Y", controller="csv")
    assert [a["axis"] for a in only_y["axes"]] == ["Y"]


@pytest.mark.parametrize("job, cli, python, code", [
    ("iso", ["{two}", "--machine", "M01", "--axis", "Y"], ({"data": "{two}", "machine": "M01",
                                                          "axis": "Y"}), 0),
    ("targets", ["{two}", "--axis", "Y", "--target", "iso"],
     {"data": "{two}", "axis": "Y", "target": "iso"}, 0),
    ("drift", ["{twin}", "--until", "2026-06-30", "--threshold-um", "8"],
     {"data": "{twin}", "until": "2026-06-30", "threshold_um": 8.0}, 0),
    ("fleet", ["{twin}", "--as-of", "2026-06-30"], {"data": "{twin}", "as_of": "2026-06-30"}, 0),
    ("circle", ["{circle}"], {"data": "{circle}"}, 0),
    ("uncertainty", ["{budget}"], {"budget": "{budget}"}, 0),
    ("volumetric", ["--targets", "5", "--seed", "3"], {"targets": 5, "seed": 3}, 0),
    ("simulate", ["--preset", "compensation", "--out", "{tmp}/sim"],
     {"preset": "compensation", "out": "{tmp}/sim-py"}, 0),
])
def test_every_job_gives_the_cli_and_python_the_same_result(job, cli, python, code, two_axes,
                                                            tmp_path, capsys):
    where = {"two": str(two_axes), "twin": str(TWIN), "tmp": str(tmp_path),
             "circle": str(ROOT / "experiments/data/circle/ballbar_xy.csv"),
             "budget": str(ROOT / "experiments/data/paper_uncertainty.toml")}
    args = [a.format(**where) for a in cli]
    params = {k: v.format(**where) if isinstance(v, str) else v for k, v in python.items()}
    from_cli = cli_json([job, *args, "--json", "--no-track"], capsys, code)
    from_python = py_json(job, **params, track=False)
    assert without_paths(from_cli) == without_paths(from_python)


def test_selection_changes_what_a_job_sees(two_axes):
    """The selection is applied, not ignored: X and Y give different figures."""
    x = py_json("iso", str(two_axes), axis="X")
    y = py_json("iso", str(two_axes), axis="Y")
    assert x != y


def test_an_unknown_parameter_is_an_error_naming_it(two_axes):
    with pytest.raises(InputError) as raised:
        bl.iso(str(two_axes), drop_outlier=True)
    assert raised.value.parameter == "drop_outlier"
    with pytest.raises(InputError) as raised:
        bl.uncertainty(ROOT / "experiments/data/paper_uncertainty.toml", machine="M01")
    assert raised.value.parameter == "machine" and "reads none" in str(raised.value)
    with pytest.raises(InputError) as raised:
        bl.iso(str(two_axes), track="yes")
    assert raised.value.parameter == "track"


def test_store_records_a_compensation_from_python_as_from_the_cli(two_axes, tmp_path, capsys):
    """``bl.compensate(..., store=S)`` records what ``--store S`` records; a job that records
    nothing refuses a store."""
    from pipeline.store.records import read_records

    stores = {}
    for how in ("cli", "python"):
        store = tmp_path / f"store-{how}"
        bl.ingest(str(two_axes), str(store))
        if how == "cli":
            assert main(["compensate", str(store), "--axis", "Y", "--controller", "csv",
                         "--out", str(tmp_path / "c"), "--store", str(store)]) == 0
        else:
            result = bl.compensate(str(store), axis="Y", controller="csv", store=str(store))
            assert result.recorded is not None
        stores[how] = read_records(str(store), "compensation")
    assert list(stores["cli"]) == list(stores["python"]) == [("M01", "Y")]
    strip = {"recorded_at", "files", "source"}
    assert ([{k: v for k, v in r.items() if k not in strip} for r in stores["cli"][("M01", "Y")]]
            == [{k: v for k, v in r.items() if k not in strip}
                for r in stores["python"][("M01", "Y")]])
    with pytest.raises(InputError) as raised:
        bl.iso(str(two_axes), store=str(tmp_path / "store-cli"))
    assert raised.value.parameter == "store"


def test_tracking_is_one_parameter_with_one_default(two_axes):
    """A tracked job logs its run by default from Python as from the CLI; ``track=False``
    logs nothing; an untracked job never touches MLflow."""
    import mlflow

    from pipeline import runner

    assert runner.TRACK is True
    logged = bl.drift(str(TWIN), until="2026-03-31").tracking
    run = mlflow.get_run(logged["run_id"])
    assert run.info.status == "FINISHED" and run.data.params
    assert bl.drift(str(TWIN), until="2026-03-31", track=False).tracking == {}
    assert bl.iso(str(two_axes)).tracking == {}


def test_every_job_is_a_python_name_running_through_the_runner():
    for job in NAMES:
        name = "check_store" if job == "store" else job.replace("-", "_")
        function = getattr(bl, name)
        assert function.__wrapped__.__name__ == name


def test_an_experiment_step_selects_and_gives_what_python_gives(two_axes, tmp_path):
    """An experiment step runs through the runner too: the same selection parameters, the
    same result."""
    from pipeline import experiment

    spec = tmp_path / "exp.toml"
    spec.write_text(f'out = "out"\n[[steps]]\njob = "iso"\n[steps.with]\ndata = "{two_axes}"\n'
                    'axis = "Y"\nout = "{out}/iso"\n')
    done = experiment.execute(experiment.load(spec, str(tmp_path / "out")))
    from_file = json.loads(dumps(done.steps[0].result.to_json()))
    assert from_file == py_json("iso", str(two_axes), axis="Y")
    assert (tmp_path / "out" / "iso" / "iso_figures.csv").is_file()
