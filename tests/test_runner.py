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
ESS = ROOT / "experiments" / "data" / "ecmc" / "ess_mcu1025_ISO230.dat"
FORBIDDEN = re.compile(r"mlflow|optuna|pipeline\.(tracking|store)\b|from pipeline import "
                       r"(tracking|store)\b")


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


def cli_json(args: list[str], capsys, code: int | None = 0) -> dict:
    """The JSON the CLI prints; ``code`` None: an alert's exit 3 is no failure."""
    capsys.readouterr()
    done = main(args)
    assert done == code if code is not None else done in (0, 3), capsys.readouterr().err
    out = capsys.readouterr().out
    try:
        return json.loads(out)
    except json.JSONDecodeError:  # JSON lines (watch's status feed): the result is the last
        return json.loads(out.strip().splitlines()[-1])


def py_json(job: str, *args, **params) -> dict:
    from pipeline import api

    name = {job: name for name, job in api.jobs().items()}[job]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = getattr(bl, name)(*args, **params)
    return json.loads(dumps(result.to_dict()))


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


def examples() -> list[tuple[str, list, dict]]:
    """Every job's ``EXAMPLE``: one call as the command line spells it (the arguments after
    ``backlash JOB``) and as Python does (keyword parameters), declared in the job's own module
    so that a new job brings its case with it. The calls use the names of ``inputs`` below in
    braces; "{side}" is a folder of each side's own (an output, a store that side ingests
    first: "{store}"), the same name in both, so the results compare with the folders
    dropped."""
    from pipeline import workflows

    return [(w.name, *w.module.EXAMPLE) for w in workflows.WORKFLOWS
            if hasattr(w.module, "EXAMPLE")]


AGREEMENT = examples()
TIMES = re.compile(r"(^|_)(seconds|elapsed|duration|recorded_at|created|datetime_start|"
                   r"datetime_complete|run_id|study)($|_)")


def test_the_agreement_covers_every_job():
    """Every job's module names its example call (``EXAMPLE``)."""
    assert sorted(job for job, *_ in AGREEMENT) == sorted(NAMES)


@pytest.fixture(scope="module")
def inputs(two_axes, tmp_path_factory) -> dict:
    """The files the agreement reads: a model, a trace, a small campaign, one scenario."""
    from tests.independent_traces import fleet_traces

    folder = tmp_path_factory.mktemp("inputs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.train(str(TWIN), model="ridge", out=str(folder / "model"), track=False)
    trace, _ = fleet_traces(seed=3, days=2)
    trace.to_parquet(folder / "trace.parquet")
    small = bl.read(str(TWIN))
    bl.write(small[small["visit"] == small["visit"].iloc[0]], folder / "small.csv")
    text = (ROOT / "experiments/hidden_effect_scenarios.toml").read_text()
    head, design = text.split("[designs.A]")[0], text.split("[designs.A]")[1].split("\n[")[0]
    (folder / "scenarios.toml").write_text(f"{head}[designs.A]{design}\nhidden = []\nnulls = 1\n")
    log = ROOT / "experiments/data/camonitor/mc_x_routine.log"
    (folder / "WATCH.toml").write_text(
        f'[source]\nprotocol = "log"\naddress = "{log}"\n[[axis]]\nmachine_id = "MC"\n'
        'axis = "X"\ncommanded = "MC:X-PosSet"\nmotor = "MC:X-PosAct"\n'
        'load = "MC:ec0-s4-EL5101-Enc-PosAct"\n')
    return {"two": str(two_axes), "twin": str(TWIN), "model": str(folder / "model"),
            "watch": str(folder / "WATCH.toml"),
            "trace": str(folder / "trace.parquet"), "small": str(folder / "small.csv"),
            "scenarios": str(folder / "scenarios.toml"), "ess": str(ESS),
            "circle": str(ROOT / "experiments/data/circle/ballbar_xy.csv"),
            "ldbb": str(ROOT / "experiments/data/stiffness/ldbb.csv"),
            "probes": str(ROOT / "experiments/data/kinematics/probes.csv"),
            "budget": str(ROOT / "experiments/data/paper_uncertainty.toml")}


def comparable(value):
    """The JSON with the files' folders and the clocks dropped."""
    if isinstance(value, dict):
        return {k: comparable(v) for k, v in value.items() if not TIMES.search(k)}
    return without_paths(value) if not isinstance(value, list) else [comparable(v)
                                                                      for v in value]


@pytest.mark.parametrize("job, cli, python", AGREEMENT, ids=[a[0] for a in AGREEMENT])
def test_every_job_gives_the_cli_and_python_the_same_result(job, cli, python, inputs,
                                                            tmp_path, capsys):
    results = both_ways(job, cli, python, inputs, tmp_path, capsys)
    assert comparable(results["cli"]) == comparable(results["python"])


def both_ways(job: str, cli: list, python: dict, inputs: dict, tmp_path, capsys) -> dict:
    """The JSON of ``backlash JOB CLI... --json`` and of ``bl.<job>(**PYTHON)``, each side
    with folders of its own under ``tmp_path``."""
    results = {}
    for side in ("cli", "python"):
        where = {**inputs, "side": str(tmp_path / side / "x"), "store": str(tmp_path / side / "s"),
                 "base": str(tmp_path / side)}
        (tmp_path / side).mkdir()
        if "{store}" in " ".join(cli):
            bl.ingest(inputs["two"], where["store"])
        if side == "cli":
            args = [a.format(**where) for a in cli]
            results[side] = cli_json([job, *args, "--json", "--no-track"], capsys,
                                     code=None)
        else:
            params = {k: v.format(**where) if isinstance(v, str) else v
                      for k, v in python.items()}
            results[side] = py_json(job, **params, track=False)
    return results


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


def test_a_workflow_is_handed_its_store_and_never_opens_one():
    """A job whose table offers ``store`` records its result through its record
    (``Workflow.records``: the function takes no ``store``; the runner opens the store and
    records), is handed the store opened as its record says (``Workflow.store_access``), or
    reads the store's records through its Source (``fleet``, ``drift``)."""
    import inspect

    from pipeline.workflows import WORKFLOWS

    for record in WORKFLOWS:
        takes = "store" in inspect.signature(record.function).parameters
        assert not (record.records and record.store_access), record.name
        if record.records is not None:
            assert "store" in record.parameters and not takes, record.name
        elif takes:
            assert record.store_access is not None or record.source, record.name


def test_the_runner_opens_the_store_a_job_operates_on_as_its_record_says(two_axes, tmp_path,
                                                                         monkeypatch):
    """ingest makes a new store (``write``), void is handed the opened ``Store``, a check
    opens for writing only with ``repair`` (``write if repair``), watch records into an
    existing store only (``record``): each refusal the one line it was, before any work."""
    import functools

    from pipeline.store.base import Store
    from pipeline.workflows import workflow

    store = tmp_path / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the new store's note
        assert bl.ingest(str(two_axes), store).new_store
    module, handed = workflow("void").module, []
    original = module.void

    @functools.wraps(original)
    def void(store, **params):
        handed.append(store)
        return original(store, **params)

    monkeypatch.setattr(module, "void", void)
    done = bl.void(str(store), machine="M01", axis="Y", reason="r")
    assert isinstance(handed[0], Store) and done.store == str(store) and done.tests
    new = tmp_path / "new"
    with pytest.raises(InputError, match="no such store"):
        bl.void(str(new), machine="M01", axis="Y", reason="r")
    with pytest.raises(InputError, match="no such file or store folder") as read:
        bl.check_store(str(new))
    with pytest.raises(InputError, match=r"no such store \(no manifest\)") as written:
        bl.check_store(str(new), repair=True)
    assert read.value.parameter == written.value.parameter == "store"
    with pytest.raises(InputError, match="holds no store yet") as watched:
        bl.watch(str(tmp_path / "WATCH.toml"), store=str(new))  # the store before the config
    assert watched.value.parameter == "store" and not new.exists()


def test_the_records_are_checked_before_the_result_is_written(tmp_path, capsys):
    """A result the store would refuse (circles without their date) writes nothing, from
    Python as from the command line; the same circles dated record their backlash, and
    ``result.recorded`` says so."""
    import pandas as pd

    from pipeline.store.records import read_records

    store = tmp_path / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.ingest(str(TWIN), store)
    dated = ROOT / "experiments/data/circle/ballbar_xy.csv"
    undated = tmp_path / "undated.csv"
    pd.read_csv(dated).drop(columns="started_at").to_csv(undated, index=False)
    with pytest.raises(InputError, match="needs its date"):
        bl.circle(str(undated), store=str(store), out=tmp_path / "py")
    assert main(["circle", str(undated), "--out", str(tmp_path / "cli"), "--store",
                 str(store)]) == 2
    assert not (tmp_path / "py").exists() and not (tmp_path / "cli").exists()
    assert read_records(str(store), "ballbar") == {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = bl.circle(str(dated), store=str(store), out=tmp_path / "py")
    assert result.recorded.added == 2 and (tmp_path / "py" / "circles.csv").is_file()
    assert bl.circle(str(dated)).recorded is None


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
    from_file = json.loads(dumps(done.steps[0].result.to_dict()))
    assert from_file == py_json("iso", str(two_axes), axis="Y")
    assert (tmp_path / "out" / "iso" / "iso_figures.csv").is_file()
