"""`backlash run`: experiment files are data, checked before anything runs, confined to their
output folder, and run through each command's own `run(args)`."""

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
file = "{source}"
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
    assert experiment.execute(experiment.load(spec)) == 0
    assert len(pd.read_parquet(out / "psi.parquet")) == 50
    assert len(pd.read_csv(out / "conv" / "psi.csv")) == 50

    import mlflow

    runs = mlflow.search_runs(experiment_names=["experiments"])
    assert list(runs["tags.mlflow.runName"]) == ["tiny"]
    assert runs["metrics.step_1_exit_code"].iloc[0] == 0
    assert artifacts(runs["run_id"].iloc[0]) == {"exp.toml", "out/psi.parquet",
                                                 "out/conv/psi.csv"}


def test_namespace_is_the_parser_defaults_plus_the_step_options(tmp_path, psi_file):
    spec = write_spec(tmp_path, f"""
[[steps]]
command = "drift"
[steps.with]
data = "{psi_file}"
threshold_um = 4
out = "drift"
""")
    (step,) = experiment.load(spec).steps
    args = step.args
    assert args.threshold_um == 4.0 and isinstance(args.threshold_um, float)
    assert (args.alpha, args.min_jump_sigma, args.json, args.format) == (0.05, 3.0, False, "auto")
    assert args.model is None
    assert args.out == str((tmp_path / "out" / "drift").resolve())  # relative to the out folder
    assert args.data == str(psi_file.resolve())
    assert step.argv[:3] == ["drift", str(psi_file.resolve()), "--out"]


@pytest.mark.parametrize("library_error", [False, True])
def test_failing_step_stops_the_experiment(tmp_path, capsys, monkeypatch, library_error):
    bad = tmp_path / "bad.csv"
    bad.write_text("machine_id,axis\nM1,X\n")
    if library_error:  # library code names the parameter in a ValueError
        def refuse(args):
            raise ValueError("alpha must lie in (0, 1), got 2 (bad.csv)")

        monkeypatch.setattr(experiment.commands()["convert"], "run", refuse)
    spec = write_spec(tmp_path, convert_step(bad, "{out}/x.csv")
                      + convert_step(bad, "{out}/never-reached.csv"))
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "backlash convert: error: " in err and "bad.csv" in err and "Traceback" not in err
    assert "step 1 failed with exit code 2" in err and "never-reached" not in err
    assert not (tmp_path / "out" / "x.csv").exists()


def test_input_an_earlier_step_should_have_written_is_checked_when_its_step_starts(
        tmp_path, psi_file, capsys):
    spec = write_spec(tmp_path, convert_step(psi_file, "{out}/a.csv")
                      + convert_step("{out}/never-written.csv", "{out}/b.csv"))
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "never-written.csv' (no earlier step wrote it)" in err
    assert (tmp_path / "out" / "a.csv").is_file() and not (tmp_path / "out" / "b.csv").exists()


# --------------------------------------------------------------------------- refusals
STEP = '[[steps]]\ncommand = "convert"\n'


@pytest.mark.parametrize("body, message", [
    ("name = \n", "invalid TOML"),
    ('name = "empty"\n', "no [[steps]]"),
    ('outdir = "x"\n' + STEP, "unknown top-level key 'outdir'; expected name, description"),
    ("name = 3\n" + STEP, "'name' must be a string, got an integer"),
    ('steps = "iso"\n', "'steps' must be an array of tables"),
    ('steps = ["iso"]\n', "step 1: expected a table"),
    ('[[steps]]\ncommand = "bake"\n', "step 1: unknown command 'bake'"),
    ('[[steps]]\ncommand = ["iso"]\n', "step 1: unknown command ['iso']"),
    ('[[steps]]\ntitle = "no command"\n', "step 1: unknown command None"),
    ('[[steps]]\ncommand = "run"\n', "step 1: unknown command 'run'"),
    ('[[steps]]\ncommand = "iso"\nargs = ["x"]\n', "step 1: unknown key 'args'; expected title, command, with (a command's options go in "),
    ('[[steps]]\ncommand = "iso"\nwith = "x"\n', "'with' must be a table of options"),
    ('[[steps]]\ncommand = "iso"\ntitle = 1\n', "'title' must be a string"),
    (STEP + '[steps.with]\nout = "{out}/a.csv"\nbogus = 1\n', "unknown option 'bogus'"),
    ('[[steps]]\ncommand = "drift"\n[steps.with]\n"threshold-um" = 4\n',
     "unknown option 'threshold-um' (write it as 'threshold_um')"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\n', "missing required option 'out'"),
    ('[[steps]]\ncommand = "simulate"\n[steps.with]\nout = "{out}/t"\nseed = "abc"\n',
     "option 'seed': expected a seed, got 'abc'"),
    ('[[steps]]\ncommand = "simulate"\n[steps.with]\nout = "{out}/t"\nseed = 1.5\n',
     "option 'seed': expected a seed, got 1.5"),
    ('[[steps]]\ncommand = "simulate"\n[steps.with]\nout = "{out}/t"\nseed = [1, 2]\n',
     "option 'seed': expected a single value, got an array"),
    ('[[steps]]\ncommand = "simulate"\n[steps.with]\nout = "{out}/t"\nseed = true\n',
     "option 'seed': expected a number, got a boolean"),
    ('[[steps]]\ncommand = "iso"\n[steps.with]\nfile = "{here}/exp.toml"\njson = "yes"\n',
     "option 'json': expected true or false, got a string"),
    ('[[steps]]\ncommand = "iso"\n[steps.with]\nfile = "{here}/exp.toml"\nformat = "xml"\n',
     "option 'format': expected one of auto, canonical, paper, ecmc, rtl, got 'xml'"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "{outdir}/a.csv"\n',
     "unknown placeholder {outdir} in '{outdir}/a.csv'; expected {data}, {out}, {here}"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "{out!r}/a.csv"\n',
     "unknown placeholder {out}"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "{out/a.csv"\n',
     "malformed placeholder"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "{out}/../../x.csv"\n',
     "lies outside the experiment's output folder"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "../x.csv"\n',
     "lies outside the experiment's output folder"),
    (STEP + '[steps.with]\nfile = "{here}/exp.toml"\nout = "/tmp/elsewhere.csv"\n',
     "lies outside the experiment's output folder"),
    ('[[steps]]\ncommand = "iso"\n[steps.with]\nfile = "{here}/exp.toml"\n'
     + 'plot = "{here}/chart.png"\n', "option 'plot': "),
    (STEP + '[steps.with]\nfile = "missing.csv"\nout = "{out}/a.csv"\n',
     "option 'file': no such file or folder"),
    ('[[steps]]\ncommand = "tune"\n[steps.with]\ndata = "{here}/exp.toml"\n',
     "give option 'storage'"),
    ('[[steps]]\ncommand = "tune"\n[steps.with]\ndata = "{here}/exp.toml"\n'
     + 'storage = "sqlite:///{here}/optuna.db"\n', "lies outside the experiment's output folder"),
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


@pytest.mark.parametrize("flags, kwargs, role", [
    (["--out"], {}, "output"), (["--plot"], {"metavar": "OUT.png"}, "output"),
    (["--report-out"], {}, "output"), (["data"], {}, "input"),
    (["--model"], {"metavar": "DIR"}, "input"), (["source"], {"metavar": "DATA|MODEL_DIR"}, "input"),
    (["--config"], {"metavar": "FILE.toml"}, "input"), (["--model"], {}, None),
    (["--storage"], {}, "storage"), (["--seed"], {"type": int}, None)])
def test_path_role_of_an_option(flags, kwargs, role):
    import argparse

    action = argparse.ArgumentParser().add_argument(*flags, **kwargs)
    assert experiment.path_role(action) == role
