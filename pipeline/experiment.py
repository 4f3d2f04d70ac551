"""Declarative experiments: a TOML file names its data, steps and parameters.

```toml
name = "demo"
description = "..."
out = "demo-out"               # output folder, relative to the working directory

[[steps]]
title = "ISO 230-2 analysis of a real test"
command = "iso"
args = ["{data}/ecmc/ess_mcu1025_ISO230.dat", "--plot", "{out}/ess_iso.png"]
```

``{here}`` is the experiment file's folder, ``{data}`` its ``data`` subfolder and ``{out}`` the
output folder. Each step is one ``backlash`` subcommand run in-process; the whole experiment is
one MLflow run (steps that track their own runs nest under it).
"""

from __future__ import annotations

import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import InputError


@dataclass
class Step:
    command: str
    args: list[str]
    title: str = ""


@dataclass
class Experiment:
    name: str
    path: Path
    out: Path
    steps: list[Step] = field(default_factory=list)
    description: str = ""


def load(path, out: str | None = None) -> Experiment:
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("cannot read experiment: no such file", file=path) from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", file=path) from None
    from pipeline.cli import COMMANDS

    out_dir = Path(out or spec.get("out", f"{spec.get('name', path.stem)}-out"))
    values = {"here": str(path.parent.resolve()), "data": str((path.parent / "data").resolve()),
              "out": str(out_dir)}
    steps = []
    for i, raw in enumerate(spec.get("steps", []), start=1):
        command = raw.get("command")
        if command not in COMMANDS or command == "run":
            raise InputError(f"step {i}: unknown command {command!r}; expected one of "
                             f"{', '.join(c for c in COMMANDS if c != 'run')}", file=path)
        args = [str(a).format(**values) for a in raw.get("args", [])]
        steps.append(Step(command, args, raw.get("title", command)))
    if not steps:
        raise InputError("no [[steps]]: an experiment needs at least one step", file=path)
    return Experiment(spec.get("name", path.stem), path, out_dir, steps,
                      spec.get("description", ""))


def execute(experiment: Experiment) -> int:
    """Run every step in order; stop at the first failing step and return its exit code."""
    from pipeline import tracking
    from pipeline.cli import main

    experiment.out.mkdir(parents=True, exist_ok=True)
    worst = 0
    with tracking.run("experiments", experiment.name) as active:
        import mlflow

        mlflow.log_artifact(str(experiment.path))
        for i, step in enumerate(experiment.steps, start=1):
            print(f"\n[{i}/{len(experiment.steps)}] {step.title}\n$ backlash {step.command} "
                  f"{' '.join(step.args)}", file=sys.stderr, flush=True)
            code = main([step.command, *step.args])
            mlflow.log_metric(f"step_{i}_exit_code", code)
            if code not in (0, 3):  # 3 is an alert, not a failure (drift monitoring)
                print(f"step {i} failed with exit code {code}", file=sys.stderr)
                return code
            worst = max(worst, code)
        mlflow.log_artifacts(str(experiment.out), artifact_path="out")
        print(f"\nexperiment {experiment.name!r}: MLflow run {active.info.run_id} in "
              f"{tracking.tracking_uri()}; outputs in {experiment.out}/", file=sys.stderr)
    return worst
