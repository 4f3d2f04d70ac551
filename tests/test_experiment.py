"""`backlash run`: experiment files are data, checked before anything runs, confined to their
output folder, and run through the workflows (``workflow(job).function(**table)``)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from pipeline import cli, experiment
from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]


def write_spec(tmp_path, body: str, out: str | None = None) -> Path:
    spec = tmp_path / "exp.toml"
    head = f'out = "{out or tmp_path / "out"}"\n'
    spec.write_text(head + body, encoding="utf-8")
    return spec


def convert_step(source, target="{out}/psi.parquet") -> str:
    return f"""
[[steps]]
title = "convert"
command = "convert"
[steps.with]
data = "{source}"
out = "{target}"
"""


def artifacts(run_id, path=None) -> set[str]:
    import mlflow

    found = set()
    for a in mlflow.MlflowClient().list_artifacts(run_id, path):
        found |= artifacts(run_id, a.path) if a.is_dir else {a.path}
    return found


def test_experiment_runs_steps_and_logs_only_its_own_outputs(tmp_path, psi_file, monkeypatch):
    def no_argv(*_):
        raise AssertionError("an experiment must not replay a command line")

    folder, out, elsewhere = tmp_path / "study", tmp_path / "out", tmp_path / "cwd"
    for f in (folder / "data", out / "conv", elsewhere):
        f.mkdir(parents=True)
    shutil.copy(psi_file, folder / "data" / "psi.dat")
    shutil.copy(psi_file, folder / "beside.dat")
    (out / "notes.txt").write_text("unrelated")
    (out / "conv" / "old.csv").write_text("stale file in a step's output folder")
    spec = write_spec(folder, 'name = "tiny"\n' + convert_step("{data}/psi.dat")
                      + convert_step("beside.dat", "conv/psi.csv"), out=str(out))
    monkeypatch.chdir(elsewhere)  # inputs are relative to the file, not the working directory
    monkeypatch.setattr(cli, "main", no_argv)
    assert experiment.execute(experiment.load(spec)).code == 0
    assert len(pd.read_parquet(out / "psi.parquet")) == 50
    assert len(pd.read_csv(out / "conv" / "psi.csv")) == 50

    import mlflow

    runs = mlflow.search_runs(experiment_names=["experiments"])
    assert list(runs["tags.mlflow.runName"]) == ["tiny"]
    assert runs["metrics.step_1_exit_code"].iloc[0] == 0
    assert artifacts(runs["run_id"].iloc[0]) == {"exp.toml", "out/psi.parquet",
                                                 "out/conv/psi.csv"}


def test_step_parameters_are_the_table_with_paths_resolved(tmp_path, psi_file):
    spec = write_spec(tmp_path, f"""
[[steps]]
job = "drift"
[steps.with]
data = "{psi_file}"
threshold_um = 4
out = "drift"
""")
    (step,) = experiment.load(spec).steps
    # only what the table gives: the workflow's own defaults apply, no parser is replayed
    assert step.parameters == {"data": str(psi_file.resolve()), "threshold_um": 4}
    assert step.out == (tmp_path / "out" / "drift").resolve()  # relative to the out folder
    assert step.inputs == [psi_file.resolve()] and step.outputs == [step.out]


def test_each_step_calls_its_workflow_with_the_table_as_keywords(tmp_path, monkeypatch):
    import functools
    import json

    from pipeline.workflows import simulate

    calls = []

    original = simulate.simulate

    @functools.wraps(original)  # the same parameters
    def recorded(**params):
        calls.append(params)
        return original(**params)

    monkeypatch.setattr(simulate, "simulate", recorded)  # the record finds it by name
    spec = write_spec(tmp_path, """
[[steps]]
title = "an inline campaign"
job = "simulate"
[steps.with]
seed = 5
out = "{out}/twin"
[steps.with.config]
fleet = { visits = 2 }
plan = { repeats = 1, feeds_mm_min = [500.0], dwells_s = [3.0] }
""")
    seen = []
    result = experiment.execute(experiment.load(spec),
                                progress=lambda *args: seen.append(args))
    assert calls == [{"seed": 5, "config": {"fleet": {"visits": 2}, "plan": {
        "repeats": 1, "feeds_mm_min": [500.0], "dwells_s": [3.0]}}}]
    parameters = json.loads((tmp_path / "out" / "twin" / "parameters.json").read_text())
    assert parameters["seed"] == 5 and parameters["config"]["fleet"]["visits"] == 2
    assert seen == [(0, 1, "an inline campaign"), (1, 1, "")]
    (done,) = result.steps
    assert result.code == 0 and set(done.files) == {"readings", "truth", "visits",
                                                     "parameters"}


def test_a_tracked_job_is_logged_nested_in_the_experiments_run(tmp_path, monkeypatch,
                                                                 psi_file):
    """A step runs through the runner: a tracked job's result is logged as a run nested in
    the experiment's; an untracked job's is not logged."""
    import dataclasses

    from pipeline.tracking import runs as tracking

    logged = []
    monkeypatch.setattr(tracking, "log_result", lambda result, **kw: logged.append(kw) or {})
    spec = write_spec(tmp_path, convert_step(psi_file, "{out}/a.csv"))
    assert experiment.execute(experiment.load(spec)).code == 0
    assert logged == []  # convert is not a tracked job
    from pipeline import workflows

    monkeypatch.setitem(workflows._BY_NAME, "convert",
                        dataclasses.replace(workflows.workflow("convert"), tracked=True))
    assert experiment.execute(experiment.load(spec)).code == 0
    assert logged == [{"nested": True}]


@pytest.mark.parametrize("library_error", [False, True])
def test_failing_step_stops_the_experiment_and_leaves_no_empty_folder(
        tmp_path, capsys, monkeypatch, library_error):
    bad = tmp_path / "bad.csv"
    bad.write_text("machine_id,axis\nM1,X\n")
    if library_error:  # library code names the parameter in a ValueError

        from pipeline.workflows import convert

        def refuse(data, out=None, format="auto"):
            raise ValueError("alpha must lie in (0, 1), got 2 (bad.csv)")

        monkeypatch.setattr(convert, "convert", refuse)
    spec = write_spec(tmp_path, convert_step(bad, "{out}/sub/x.csv")
                      + convert_step(bad, "{out}/never-reached.csv"))
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    # the error line naming the step is the first line the run prints: no step header before
    lines = [line for line in err.strip().splitlines() if " INFO mlflow." not in line]
    assert len(lines) == 1 and "Traceback" not in err and "[1/2]" not in err, err
    assert lines[0].startswith("backlash run: error: step 1 (convert): ") and "bad.csv" in err
    assert "never-reached" not in err and "[2/2]" not in err
    assert not (tmp_path / "out").exists()  # nothing half-written, no empty folder


def test_input_an_earlier_step_should_have_written_is_checked_when_its_step_starts(
        tmp_path, psi_file, capsys):
    spec = write_spec(tmp_path, convert_step(psi_file, "{out}/a.csv")
                      + convert_step("{out}/never-written.csv", "{out}/b.csv"))
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "never-written.csv' (no earlier step wrote it)" in err
    assert (tmp_path / "out" / "a.csv").is_file() and not (tmp_path / "out" / "b.csv").exists()


# --------------------------------------------------------------------------- refusals
STEP = '[[steps]]\njob = "convert"\n'
SIM = '[[steps]]\njob = "simulate"\n[steps.with]\nout = "{out}/t"\n'
ISO = '[[steps]]\njob = "iso"\n[steps.with]\ndata = "{here}/exp.toml"\n'


def _has_workflow(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(f"pipeline.workflows.{name}") is not None


TUNE = pytest.mark.skipif(not _has_workflow("tune"), reason="no tune workflow")


@pytest.mark.parametrize("body, message", [
    ("name = \n", "invalid TOML"),
    ('name = "empty"\n', "no [[steps]]"),
    ('outdir = "x"\n' + STEP, "unknown key 'outdir'; expected name, description, out, steps"),
    ("name = 3\n" + STEP, "column 'name': expected text, got 3"),
    ('steps = "iso"\n', "column 'steps': expected a list of tables, got 'iso'"),
    ('steps = ["iso"]\n', "column 'steps[1]': expected a table, got 'iso'"),
    ('[[steps]]\njob = "bake"\n', "step 1: unknown job 'bake'; expected one of convert, ingest, store, void, iso"),
    ('[[steps]]\ncommand = "bake"\n', "step 1: unknown job 'bake'"),
    ('[[steps]]\ncommand = ["iso"]\n', "column 'steps[1].command': expected text"),
    ('[[steps]]\ntitle = "no job"\n', "step 1: no job given; expected one of convert"),
    ('[[steps]]\njob = "run"\n', "step 1: unknown job 'run'"),
    ('[[steps]]\njob = "iso"\ncommand = "iso"\n', "step 1: give 'job' or 'command', not both"),
    ('[[steps]]\njob = "iso"\nargs = ["x"]\n',
     "unknown key 'steps[1].args'; expected title, job, command, with"),
    ('[[steps]]\njob = "iso"\nwith = "x"\n', "column 'steps[1].with': expected a table"),
    ('[[steps]]\njob = "iso"\ntitle = 1\n', "column 'steps[1].title': expected text"),
    (STEP + '[steps.with]\nout = "{out}/a.csv"\nbogus = 1\n',
     "step 1 (convert): unknown parameter 'bogus'; expected one of data, out, format"),
    ('[[steps]]\njob = "drift"\n[steps.with]\n"threshold-um" = 4\n',
     "unknown parameter 'threshold-um' (write it as 'threshold_um')"),
    (STEP + '[steps.with]\nout = "{out}/a.csv"\n', "step 1 (convert): missing parameter 'data'"),
    (SIM + 'seed = "abc"\n', "step 1 (simulate): parameter 'seed': must be an int in the range"),
    (SIM + 'seed = 1.5\n', "parameter 'seed': must be an int in the range [0, 4294967295]"),
    (SIM + 'seed = [1, 2]\n', "parameter 'seed': must be an int"),
    (SIM + 'preset = 3\n', "parameter 'preset': must be an instance of 'str'"),
    (ISO + 'drop_outliers = "yes"\n', "parameter 'drop_outliers': must be an instance of"),
    (ISO + 'format = "xml"\n', "parameter 'format': must be a str among"),
    (ISO + 'json = true\n', "unknown parameter 'json'"),
    # every key of a step has its type: one line naming the file, the step and the key
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = 5\n',
     "exp.toml: step 1 (convert): parameter 'out': expected a path (text), got 5"),
    (ISO + 'out = ["{out}/a"]\n', "step 1 (iso): parameter 'out': expected a path (text), got"),
    ('[[steps]]\njob = "iso"\n[steps.with]\ndata = 5\n',
     "step 1 (iso): parameter 'data': expected a path (text) or a list of paths, got 5"),
    ('[[steps]]\njob = "iso"\n[steps.with]\ndata = ["{here}/exp.toml", 1]\n',
     "step 1 (iso): parameter 'data': expected a path (text) or a list of paths, got 1"),
    ('[[steps]]\njob = "rank"\n[steps.with]\ndata = true\n',
     "step 1 (rank): parameter 'data': expected a path (text) or a list of paths, got true"),
    ('[[steps]]\njob = "drift"\n[steps.with]\ndata = {a = 1}\n',
     "step 1 (drift): parameter 'data': must be an instance of 'str', an instance of 'os.PathLike'"),
    (SIM + 'seed = true\n', ("step 1 (simulate): parameter 'seed': must be an int in the range "
     "[0, 4294967295]; got True")),
    (SIM + 'compensation = 5\n', ("step 1 (simulate): parameter 'compensation': must be an "
     "instance of 'dict' or None; got 5")),
    ('[[steps]]\njob = "drift"\n[steps.with]\ndata = "{here}/exp.toml"\nthreshold_um = true\n',
     ("step 1 (drift): parameter 'threshold_um': must be a float in the range (0.0, inf) or "
     "None; got True")),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "{outdir}/a.csv"\n',
     "unknown placeholder {outdir} in '{outdir}/a.csv'; expected {data}, {out}, {here}"),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "{out!r}/a.csv"\n',
     "unknown placeholder {out}"),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "{out/a.csv"\n',
     "malformed placeholder"),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "{out}/../../x.csv"\n',
     "lies outside the experiment's output folder"),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "../x.csv"\n',
     "lies outside the experiment's output folder"),
    (STEP + '[steps.with]\ndata = "{here}/exp.toml"\nout = "/tmp/elsewhere.csv"\n',
     "lies outside the experiment's output folder"),
    (ISO + 'out = "{here}/chart"\n', "step 1 (iso): parameter 'out': "),
    (STEP + '[steps.with]\ndata = "missing.csv"\nout = "{out}/a.csv"\n',
     "parameter 'data': no such file or folder"),
    pytest.param('[[steps]]\njob = "tune"\n[steps.with]\ndata = "{here}/exp.toml"\n',
                 "give parameter 'storage'", marks=TUNE),
    pytest.param('[[steps]]\njob = "tune"\n[steps.with]\ndata = "{here}/exp.toml"\n'
                 + 'storage = "sqlite:///{here}/optuna.db"\n',
                 "lies outside the experiment's output folder", marks=TUNE),
])
def test_bad_experiment_file_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, body,
                                                                    message):
    spec = write_spec(tmp_path, body)
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert len(err.strip().splitlines()) == 1 and err.startswith("backlash run: error: ")
    assert not (tmp_path / "out").exists()


def test_output_through_a_symlink_out_of_the_folder_is_refused(tmp_path, capsys, psi_file):
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (out / "link").symlink_to(outside, target_is_directory=True)
    spec = write_spec(tmp_path, convert_step(psi_file, "{out}/link/a.csv"))
    assert main(["run", str(spec)]) == 2
    assert "lies outside the experiment's output folder" in capsys.readouterr().err
    assert list(outside.iterdir()) == []


@pytest.mark.parametrize("out, message", [("{data}/out", "'out': unknown placeholder {data}"),
                                          ("", "the output folder is empty")])
def test_bad_output_folder(tmp_path, capsys, psi_file, out, message):
    spec = tmp_path / "exp.toml"
    spec.write_text(f'out = "{out}"\n' + convert_step(psi_file), encoding="utf-8")
    assert main(["run", str(spec)]) == 2
    assert message in capsys.readouterr().err


def experiment_files() -> list[Path]:
    """The shipped experiment files: TOML files with steps (parameter sets have none)."""
    import tomllib

    return sorted(p for p in (REPO / "experiments").rglob("*.toml")
                  if "steps" in tomllib.loads(p.read_text(encoding="utf-8")))


def test_the_demo_is_an_experiment_file():
    assert REPO / "experiments" / "demo.toml" in experiment_files()


@pytest.mark.parametrize("path", experiment_files(), ids=lambda p: p.name)
def test_shipped_experiments_are_valid_and_stay_in_their_folder(path, tmp_path):
    loaded = experiment.load(path, str(tmp_path / "out"))
    assert loaded.steps
    for step in loaded.steps:
        assert step.outputs, f"step {step.index} writes nothing"
        assert all(experiment.inside(p, loaded.out) for p in step.outputs)


def test_inputs_are_the_records_and_out_is_the_results_folder(tmp_path, psi_file):
    """Which parameters are paths comes from the workflow record, not from option names."""
    spec = write_spec(tmp_path, f"""
[[steps]]
job = "predict"
[steps.with]
model = "{{out}}/models/m"
plan = "{psi_file}"
out = "forecast.csv"
""")
    (step,) = experiment.load(spec).steps
    out = (tmp_path / "out").resolve()
    assert step.parameters == {"model": str(out / "models" / "m"), "plan": str(psi_file.resolve())}
    assert step.inputs == [out / "models" / "m", psi_file.resolve()]
    assert step.out == out / "forecast.csv"
