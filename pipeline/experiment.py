"""Experiment files: a TOML file names its steps, each a job and its parameters; ``backlash run``
runs them through the same workflows the CLI and the Python API call.

```toml
name = "demo"                       # MLflow run name (default: the file name)
description = "..."
out = "demo-out"                    # output folder, relative to the working directory

[[steps]]
title = "ISO 230-2 analysis of a real test"
job = "iso"                         # a workflow (pipeline.workflows.NAMES); ``command`` also
[steps.with]                        # its keyword parameters, by their Python names
data = "{data}/ecmc/ess_mcu1025_ISO230.dat"
out = "{out}/ess_iso"               # where the result writes its files
```

Placeholders: ``{here}`` the file's folder, ``{data}`` its ``data`` subfolder, ``{out}`` the
output folder; any other ``{name}`` is an error (write ``{{`` for a literal brace).

The file is checked completely before anything runs: only the keys above, a known job, its
parameters known, required ones present, values within the workflow's constraints
(``PARAMETERS``). Parameters that name files to read (the workflow record's ``inputs``) are
resolved relative to the experiment file and must exist, unless an earlier step writes them
inside the output folder (then they are checked when their step starts). ``out`` is resolved
relative to the output folder and must lie inside it, as must a SQLite ``storage``.

Each step runs through the one runner, as the CLI and ``bl.<job>`` do
(``pipeline.runner.run(job, **parameters, out=out)``): it writes the result (a workflow that
takes ``out`` itself writes it) and logs a tracked job's result to MLflow, nested in the
experiment's run. The whole experiment is one MLflow run; its artifacts are the experiment file and the
files the steps wrote (files already in the output folder are left out). A failing step stops
the experiment: what it half wrote is removed, and so are folders left empty; the steps before
it keep their files.
"""

from __future__ import annotations

import inspect
import os
import string
import sys
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.config import read_config
from features.readings.errors import InputError, Progress, report
from features.readings.selection import NAMES as SELECTION
from pipeline.results import ALERT_EXIT, Result
from pipeline.store import is_url

SQLITE = "sqlite:///"


# --------------------------------------------------------------------------- the file
@dataclass
class StepFile:
    """One ``[[steps]]`` table as written."""

    title: str | None = None
    job: str | None = None
    command: str | None = None  # the job's CLI name: the same thing as ``job``
    parameters: dict = field(default_factory=dict, metadata={"key": "with"})


@dataclass
class ExperimentFile:
    """An experiment file as written."""

    name: str | None = None
    description: str = ""
    out: str | None = None
    steps: list[StepFile] = field(default_factory=list)


# --------------------------------------------------------------------------- checked form
@dataclass
class Step:
    """A step ready to run: the job, its keyword parameters (paths resolved) and where its
    result is written (``out``; None when the workflow writes ``out`` itself or nothing)."""

    index: int
    title: str
    job: str
    parameters: dict
    out: Path | None = None
    inputs: list[Path] = field(default_factory=list)
    outputs: list[Path] = field(default_factory=list)


@dataclass
class Experiment:
    name: str
    path: Path
    out: Path
    steps: list[Step] = field(default_factory=list)
    description: str = ""


@dataclass
class StepResult:
    """What one step gave: its workflow result and the files written, by role."""

    step: Step
    result: Result
    files: dict[str, Path]
    code: int = 0  # 0, or ALERT_EXIT when the result carries alerts

    def paths(self) -> list[Path]:
        """Every file written, in order (a role may hold several files)."""
        found = []
        for value in self.files.values():
            found += [Path(v) for v in value] if isinstance(value, (list, tuple)) else [
                Path(value)]
        return found


@dataclass
class ExperimentResult(Result):
    """A finished experiment: every step's result, the MLflow run and the exit code."""

    experiment: Experiment
    steps: list[StepResult] = field(default_factory=list)
    run_id: str | None = None
    tracking_uri: str | None = None

    @property
    def code(self) -> int:
        """0, or 3 when a step raised an alert."""
        return max((s.code for s in self.steps), default=0)

    def to_dict(self) -> dict:
        return {"name": self.experiment.name, "out": str(self.experiment.out),
                "run_id": self.run_id, "code": self.code,
                "steps": [{"index": s.step.index, "title": s.step.title, "job": s.step.job,
                           "code": s.code, "files": [str(p) for p in s.paths()]}
                          for s in self.steps]}


# --------------------------------------------------------------------------- loading
def load(path, out: str | None = None) -> Experiment:
    """Read and check an experiment file completely; nothing runs and nothing is written.

    Parameters
    ----------
    path : str or Path
        The experiment file.
    out : str, optional
        Output folder (default: the file's ``out``, else ``<name>-out``), relative to the
        working directory.
    """
    from features.readings.fileio import check_output

    path = Path(path)
    spec = read_config(path, ExperimentFile, what="experiment")
    here = path.parent.resolve()
    name = spec.name if spec.name is not None else path.stem
    if out is None:
        out = expand(spec.out if spec.out is not None else f"{name}-out",
                     {"here": str(here)}, path, "'out'")
    if not out.strip():
        raise InputError("the output folder is empty; give 'out' a folder name", file=path)
    out_dir = Path(os.path.realpath(out))
    check_output(out_dir, "folder", "out")
    if not spec.steps:
        raise InputError("no [[steps]]: an experiment needs at least one step", file=path)
    values = {"data": str(here / "data"), "out": str(out_dir), "here": str(here)}
    steps = [load_step(i, raw, values, path) for i, raw in enumerate(spec.steps, start=1)]
    return Experiment(name, path, out_dir, steps, spec.description)


def load_step(index: int, raw: StepFile, values: dict, path: Path) -> Step:
    """A checked step: known job and parameters, placeholders filled, paths resolved."""
    record = _record(index, raw, path)
    where = f"step {index} ({record.name})"
    signature = inspect.signature(record.function)
    accepted = [n for n, p in signature.parameters.items()
                if n != "progress" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    # the runner's own: where the result goes, the test selection, tracking (pipeline.runner)
    allowed = accepted + [n for n in ("out", *SELECTION, "track") if n not in accepted]
    given = raw.parameters
    unknown = [k for k in given if k not in allowed]
    if unknown:
        hint = unknown[0].replace("-", "_").lstrip("_")
        hint = f" (write it as {hint!r})" if hint in allowed else ""
        raise InputError(f"{where}: unknown parameter {unknown[0]!r}{hint}; expected one of "
                         f"{', '.join(allowed)}", file=path)
    missing = [n for n in accepted if n not in given
               and signature.parameters[n].default is inspect.Parameter.empty]
    if missing:
        raise InputError(f"{where}: missing parameter {missing[0]!r}", file=path)

    step = Step(index, raw.title or record.name, record.name, {})
    for name, value in given.items():
        label = f"{where}: parameter {name!r}"
        value = _expand_all(value, values, path, label)
        if name in record.inputs:
            value = _place(value, "input", step, values, path, label)
        elif name == "out":
            value = _place(value, "output", step, values, path, label)
        step.parameters[name] = value
    if "storage" in accepted:
        _check_storage(step, Path(values["out"]), path, where)
    if "out" in step.parameters and "out" not in accepted:
        step.out = Path(step.parameters.pop("out"))
    _check_values(record, {k: v for k, v in step.parameters.items() if k in accepted}, path, where)
    return step


def _record(index: int, raw: StepFile, path: Path):
    """The workflow record of a step's job (``job`` or ``command``)."""
    from pipeline.workflows import NAMES, workflow

    if raw.job is not None and raw.command is not None:
        raise InputError(f"step {index}: give 'job' or 'command', not both", file=path)
    job = raw.job if raw.job is not None else raw.command
    if job not in NAMES:
        given = "no job given" if job is None else f"unknown job {job!r}"
        raise InputError(f"step {index}: {given}; expected one of {', '.join(NAMES)}",
                         file=path)
    return workflow(job)


def _check_values(record, params: dict, path: Path, where: str) -> None:
    """The workflow's own constraints (``PARAMETERS``), before anything runs."""
    from pipeline.workflows import check_params

    module = sys.modules[f"pipeline.workflows.{record.name.replace('-', '_')}"]  # the job's
    constraints = getattr(module, "PARAMETERS", {})
    for name in record.inputs:  # a table where only paths are read: nothing would judge it
        if isinstance(params.get(name), dict) and name not in constraints:
            raise InputError(f"{where}: parameter {name!r}: expected a path (text) or a list "
                             "of paths, got a table", file=path)
    try:
        check_params(constraints, params, record.name)
    except InputError as err:
        raise InputError(f"{where}: parameter {err.parameter!r}: {err.message}",
                         file=path) from None


def expand(text: str, values: dict, path: Path, label: str) -> str:
    """``text`` with its placeholders filled; unknown or malformed ones are an error."""
    try:
        fields = [(name, spec, conv) for _, name, spec, conv in string.Formatter().parse(text)
                  if name is not None]
    except ValueError as err:
        raise InputError(f"{label}: malformed placeholder in {text!r} ({err}); write {{{{ "
                         "for a literal brace", file=path) from None
    for name, spec, conv in fields:
        if name not in values or spec or conv:
            allowed = ", ".join(f"{{{v}}}" for v in values)
            raise InputError(f"{label}: unknown placeholder {{{name}}} in {text!r}; expected "
                             f"{allowed}", file=path)
    return text.format(**values)


def _expand_all(value, values, path, label):
    if isinstance(value, str):
        return expand(value, values, path, label)
    if isinstance(value, list):
        return [_expand_all(v, values, path, label) for v in value]
    if isinstance(value, dict):
        return {k: _expand_all(v, values, path, label) for k, v in value.items()}
    return value


# --------------------------------------------------------------------------- paths
def _place(value, role: str, step: Step, values: dict, path: Path, label: str):
    """Resolve a path parameter: inputs against the file's folder (they must exist unless an
    earlier step writes them), outputs against the output folder (they must stay inside)."""
    if isinstance(value, list) and role == "input" and value:
        return [_place(v, role, step, values, path, label) for v in value]
    if isinstance(value, dict) and role == "input":
        return value  # an inline table (a budget, a campaign): the workflow's constraints judge
    if not isinstance(value, str):
        expected = "a path (text)" if role == "output" else "a path (text) or a list of paths"
        raise InputError(f"{label}: expected {expected}, got {_toml(value)}", file=path)
    if role == "input" and is_url(value):
        return value  # a store's URL (postgresql://...): no path to resolve
    out = Path(values["out"])
    base = Path(values["here"]) if role == "input" else out
    resolved = Path(os.path.realpath(base / Path(value).expanduser()))
    if role == "output":
        if not inside(resolved, out):
            raise InputError(f"{label}: {value!r} lies outside the experiment's output folder "
                             f"{out}; outputs must stay inside it (use {{out}}/...)", file=path)
        step.outputs.append(resolved)
    else:
        if not inside(resolved, out) and not resolved.exists():
            raise InputError(f"{label}: no such file or folder {str(resolved)!r}", file=path)
        step.inputs.append(resolved)
    return str(resolved)


def _toml(value) -> str:
    """A value as the file writes it (``5``, ``true``, ``[1]``), for messages."""
    import json

    return json.dumps(value) if isinstance(value, (bool, int, float, list, dict)) else repr(value)


def _check_storage(step: Step, out: Path, path: Path, where: str) -> None:
    """A storage URL (``tune``) is an output: SQLite files inside the output folder, given
    explicitly (the workflow's default file lies in the working directory)."""
    url = step.parameters.get("storage")
    if url is None:
        raise InputError(f"{where}: give parameter 'storage', e.g. \"{SQLITE}{{out}}/optuna.db\""
                         ": the default storage lies outside the experiment's output folder",
                         file=path)
    if isinstance(url, str) and url.startswith(SQLITE):
        db = Path(os.path.realpath(out / url[len(SQLITE):]))
        if not inside(db, out):
            raise InputError(f"{where}: parameter 'storage': {url!r} lies outside the "
                             f"experiment's output folder {out}", file=path)
        step.outputs.append(db)
        step.parameters["storage"] = f"{SQLITE}{db}"


def inside(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies below it (both already resolved)."""
    return path == folder or folder in path.parents


# --------------------------------------------------------------------------- running
def execute(experiment: Experiment, progress: Progress | None = None) -> ExperimentResult:
    """Run every step in order as one MLflow run.

    Parameters
    ----------
    experiment : Experiment
        What ``load`` returned.
    progress : callable, optional
        ``progress(done, total, title)``: called before each step (``done`` steps finished)
        and once at the end (``done == total``).

    Returns
    -------
    ExperimentResult
        Every step's result; ``code`` is 3 when a step raised an alert (drift), else 0.

    Raises
    ------
    InputError
        The first failing step's error, as one line naming the step. What that step wrote is
        removed, and so is every folder the experiment created that is left empty.
    """
    from pipeline.tracking import runs as tracking

    outcome = ExperimentResult(experiment=experiment, tracking_uri=tracking.tracking_uri())
    before = snapshot(experiment)
    folders = _folders(experiment.out)
    total = len(experiment.steps)
    with tracking.run("experiments", experiment.name) as active:
        outcome.run_id = active.info.run_id
        tracking.mlflow_module().log_artifact(str(experiment.path))
        try:
            for step in experiment.steps:
                report(progress, step.index - 1, total, step.title)
                outcome.steps.append(_run_step(step, experiment))
            report(progress, total, total, "")
        finally:
            log_outputs(experiment, before)
            if len(outcome.steps) < total:
                _remove_empty(experiment.out, folders)
    for done in outcome.steps:
        outcome.notes += done.result.notes
    return outcome


def _run_step(step: Step, experiment: Experiment) -> StepResult:
    """Call the step's workflow, write its result and log it; a failure removes what the
    step wrote and is re-raised as one line naming the step."""
    from pipeline.runner import run
    from pipeline.tracking import runs as tracking

    mlflow = tracking.mlflow_module()
    where = f"step {step.index} ({step.job})"
    before = _files_below(experiment.out)
    try:
        missing = [p for p in step.inputs if not p.exists()]
        if missing:
            raise InputError(f"no such file or folder {str(missing[0])!r} (no earlier step "
                             "wrote it)")
        out = {} if step.out is None else {"out": step.out}
        result = run(step.job, **step.parameters, **out)  # logged nested in the experiment's run
        files = dict(result.files)
    except (InputError, ValueError) as err:
        mlflow.log_metric(f"step_{step.index}_exit_code", 2)
        for f in _files_below(experiment.out) - before:  # nothing half-written stays
            f.unlink(missing_ok=True)
        line = err.line() if isinstance(err, InputError) else str(err)
        raise InputError(f"{where}: {' '.join(line.split())}") from None
    code = ALERT_EXIT if getattr(result, "alerts", None) else 0
    mlflow.log_metric(f"step_{step.index}_exit_code", code)
    return StepResult(step, result, files, code)


def _files_below(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*") if p.is_file()} if folder.is_dir() else set()


def _folders(folder: Path) -> set[Path]:
    """The folders that exist now at or below ``folder``."""
    if not folder.is_dir():
        return set()
    return {folder, *(p for p in folder.rglob("*") if p.is_dir())}


def _remove_empty(folder: Path, kept: set[Path]) -> None:
    """Remove the empty folders at or below ``folder`` that are not in ``kept``, deepest
    first."""
    if not folder.is_dir():
        return
    for path in sorted(_folders(folder) - kept, key=lambda p: len(p.parts), reverse=True):
        try:
            path.rmdir()
        except OSError:  # not empty: a finished step's files
            pass


def snapshot(experiment: Experiment) -> dict[Path, tuple]:
    """Identity (inode, size, mtime) of every file already in the steps' output paths."""
    return {f: _identity(f) for f in _files(experiment)}


def _files(experiment: Experiment) -> list[Path]:
    found = set()
    for step in experiment.steps:
        for target in step.outputs:
            if target.is_file():
                found.add(target)
            elif target.is_dir():
                found.update(p for p in target.rglob("*") if p.is_file())
    return sorted(found)


def _identity(path: Path) -> tuple:
    st = path.stat()
    return st.st_ino, st.st_size, st.st_mtime_ns


def log_outputs(experiment: Experiment, before: dict[Path, tuple]) -> None:
    """Log the files the steps wrote (new or changed since ``before``) under ``out/``."""
    mlflow = _mlflow()
    for f in _files(experiment):
        if before.get(f) == _identity(f):
            continue
        folder = f.parent.relative_to(experiment.out).as_posix()
        mlflow.log_artifact(str(f), artifact_path="out" if folder == "." else f"out/{folder}")


def _mlflow():
    from pipeline.tracking import runs as tracking

    return tracking.mlflow_module()

