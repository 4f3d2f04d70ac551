"""Experiment files: a TOML file names its steps and their options; ``backlash run`` runs them.

```toml
name = "demo"                       # MLflow run name (default: the file name)
description = "..."
out = "demo-out"                    # output folder, relative to the working directory

[[steps]]
title = "ISO 230-2 analysis of a real test"
command = "iso"                     # a backlash subcommand
[steps.with]                        # its options by their argparse dest, positional ones too
file = "{data}/ecmc/ess_mcu1025_ISO230.dat"
plot = "{out}/ess_iso.png"
```

Placeholders: ``{here}`` the file's folder, ``{data}`` its ``data`` subfolder, ``{out}`` the
output folder; any other ``{name}`` is an error (write ``{{`` for a literal brace).

The file is checked completely before anything runs: only the keys above, every step a
table, a known command, its options known and of the option's type, required ones present.
Input paths (``file``, ``data``, ``truth``, ``config``, model directories) are resolved
relative to the experiment file and must exist, unless an earlier step writes them inside the
output folder (then they are checked when their step starts). Output paths (``out``, ``plot``,
a SQLite storage) are resolved relative to the output folder and must lie inside it.

Each step calls its command's ``run(args)`` with an ``argparse.Namespace`` made of the
command's own parser defaults and the step's ``with`` table. The whole experiment is one
MLflow run (steps that track their own runs nest under it); its artifacts are the experiment
file and the files the steps wrote (files already in the output folder are left out).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import shlex
import string
import sys
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import InputError
from features.readings.fileio import read_toml
from pipeline.commands import common
from pipeline.commands.common import check_outputs, remove_created

TOP_KEYS = ("name", "description", "out", "steps")
STEP_KEYS = ("title", "command", "with")
# Options that name files or folders: by argparse dest, or by a metavar that says so
# (``DIR``, ``FILE.toml``, ``DATA|MODEL_DIR``; ``OUT.png`` for an output).
INPUT_DESTS = ("file", "data", "source", "truth", "config")
INPUT_WORDS = ("DIR", "FILE", "DATA")
OUTPUT_DESTS = ("out", "plot")
SQLITE = "sqlite:///"
ALERT_EXIT = 3  # an alert (drift monitoring) is a result, not a failure


@dataclass
class Step:
    index: int
    title: str
    command: str
    args: argparse.Namespace
    argv: list[str]  # the equivalent command line, shown to the user
    inputs: list[Path] = field(default_factory=list)
    outputs: list[Path] = field(default_factory=list)


@dataclass
class Experiment:
    name: str
    path: Path
    out: Path
    steps: list[Step] = field(default_factory=list)
    description: str = ""


# --------------------------------------------------------------------------- commands
def commands() -> dict[str, object]:
    """Every ``backlash`` subcommand module by name (``hidden_effects`` -> ``hidden-effects``),
    except ``run`` itself: an experiment does not start experiments."""
    import pipeline.commands as package

    found = {}
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        if hasattr(module, "add_arguments") and hasattr(module, "run") and info.name != "run":
            found[info.name.replace("_", "-")] = module
    return dict(sorted(found.items()))


def options(module) -> dict[str, argparse.Action]:
    """The command's argparse actions by dest, from its own ``add_arguments``."""
    from pipeline.commands.common import checked_types

    parser = argparse.ArgumentParser(add_help=False)
    module.add_arguments(parser)
    checked_types(parser)  # the same finite/count/seed checks as on the command line
    return {a.dest: a for a in parser._actions}


def path_role(action: argparse.Action) -> str | None:
    """``"input"``, ``"output"``, ``"storage"`` or None for an option that names no path."""
    metavar = action.metavar if isinstance(action.metavar, str) else ""
    if action.dest in OUTPUT_DESTS or action.dest.endswith("_out") or metavar.startswith("OUT"):
        return "output"
    if action.dest in INPUT_DESTS or any(w in metavar.upper() for w in INPUT_WORDS):
        return "input"
    if action.dest == "storage":
        return "storage"
    return None


# --------------------------------------------------------------------------- loading
def load(path, out: str | None = None) -> Experiment:
    """Read and check an experiment file completely; nothing runs and nothing is written."""
    path = Path(path)
    spec = read_toml(path, "experiment")
    _check_keys(spec, TOP_KEYS, "top-level key", path)
    for key in ("name", "description", "out"):
        if key in spec and not isinstance(spec[key], str):
            raise InputError(f"{key!r} must be a string, got {_kind(spec[key])}", file=path)
    here = path.parent.resolve()
    if out is None:
        out = expand(spec.get("out", f"{spec.get('name', path.stem)}-out"),
                     {"here": str(here)}, path, "'out'")
    if not out.strip():
        raise InputError("the output folder is empty; give 'out' a folder name", file=path)
    out_dir = Path(os.path.realpath(out))
    values = {"data": str(here / "data"), "out": str(out_dir), "here": str(here)}

    raw_steps = spec.get("steps", [])
    if not isinstance(raw_steps, list):
        raise InputError(f"'steps' must be an array of tables ([[steps]]), got "
                         f"{_kind(raw_steps)}", file=path)
    if not raw_steps:
        raise InputError("no [[steps]]: an experiment needs at least one step", file=path)
    known = commands()
    steps = [load_step(i, raw, known, values, path)
             for i, raw in enumerate(raw_steps, start=1)]
    return Experiment(spec.get("name", path.stem), path, out_dir, steps,
                      spec.get("description", ""))


def load_step(index: int, raw, known: dict, values: dict, path: Path) -> Step:
    where = f"step {index}"
    if not isinstance(raw, dict):
        raise InputError(f"{where}: expected a table ([[steps]] with title, command and "
                         f"[steps.with]), got {_kind(raw)}", file=path)
    _check_keys(raw, STEP_KEYS, "key", path, where=f"{where}: ",
                hint=" (a command's options go in [steps.with])")
    command = raw.get("command")
    if not isinstance(command, str) or command not in known:
        raise InputError(f"{where}: unknown command {command!r}; expected one of "
                         f"{', '.join(known)}", file=path)
    where = f"step {index} ({command})"
    title = raw.get("title", command)
    given = raw.get("with", {})
    if not isinstance(title, str):
        raise InputError(f"{where}: 'title' must be a string, got {_kind(title)}", file=path)
    if not isinstance(given, dict):
        raise InputError(f"{where}: 'with' must be a table of options, got {_kind(given)}",
                         file=path)
    settable = options(known[command])
    unknown = [k for k in given if k not in settable]
    if unknown:
        hint = unknown[0].replace("-", "_").lstrip("_")
        hint = f" (write it as {hint!r})" if hint in settable else ""
        raise InputError(f"{where}: unknown option {unknown[0]!r}{hint}; expected one of "
                         f"{', '.join(settable)}", file=path)
    missing = [d for d, a in settable.items() if a.required and d not in given]
    if missing:
        raise InputError(f"{where}: missing required option {missing[0]!r}", file=path)

    args = argparse.Namespace(command=command, **defaults(settable))
    step = Step(index, title, command, args, [command])
    for dest, value in given.items():
        action = settable[dest]
        label = f"{where}: option {dest!r}"
        value = _expand_all(value, values, path, label)
        value = convert(value, action, path, label)
        value = _place(value, path_role(action), step, values, path, label)
        setattr(args, dest, value)
    for dest, action in settable.items():  # in the parser's order, so positionals line up
        if dest in given:
            step.argv += _argv(action, getattr(args, dest))
    _check_storage(step, settable, Path(values["out"]), path, where)
    return step


def defaults(actions: dict[str, argparse.Action]) -> dict:
    """The values argparse gives options that are not on the command line (a string default
    goes through the option's type, as argparse does)."""
    values = {}
    for dest, action in actions.items():
        if action.default is argparse.SUPPRESS:
            continue
        value = action.default
        if isinstance(value, str) and action.type is not None:
            value = action.type(value)
        values[dest] = value
    return values


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
    return value


def convert(value, action: argparse.Action, path: Path, label: str):
    """A TOML value as the command line would give it: through the option's type and
    choices. Flags take true/false; an option taking several values takes an array."""
    if action.nargs == 0:  # store_true, store_false, store_const
        if not isinstance(value, bool):
            raise InputError(f"{label}: expected true or false, got {_kind(value)}", file=path)
        return action.const if value else action.default
    if action.nargs in ("*", "+") or isinstance(action.nargs, int):
        items = value if isinstance(value, list) else [value]
        return [_one(v, action, path, label) for v in items]
    if isinstance(value, list):
        raise InputError(f"{label}: expected a single value, got an array", file=path)
    return _one(value, action, path, label)


def _one(value, action, path, label):
    if isinstance(value, (bool, dict, list)):
        numeric = (int, float, common.finite_float, common.count, common.seed)
        wanted = "number" if action.type in numeric else "string"
        raise InputError(f"{label}: expected a {wanted}, got {_kind(value)}", file=path)
    text = value if isinstance(value, str) else str(value)
    try:
        converted = action.type(text) if action.type is not None else text
    except (TypeError, ValueError, argparse.ArgumentTypeError) as err:
        kind = getattr(action.type, "__name__", "value")
        raise InputError(f"{label}: expected {'an' if kind[0] in 'aeiou' else 'a'} {kind}, "
                         f"got {value!r} ({err})", file=path) from None
    if action.choices is not None and converted not in action.choices:
        raise InputError(f"{label}: expected one of {', '.join(map(str, action.choices))}, got "
                         f"{value!r}", file=path)
    return converted


# --------------------------------------------------------------------------- paths
def _place(value, role, step: Step, values: dict, path: Path, label: str):
    """Resolve a path option: inputs against the file's folder (they must exist unless an
    earlier step writes them), outputs against the output folder (they must stay inside)."""
    if value is None or role not in ("input", "output"):
        return value
    if isinstance(value, list):
        return [_place(v, role, step, values, path, label) for v in value]
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


def _check_storage(step: Step, settable: dict, out: Path, path: Path, where: str) -> None:
    """A storage URL (``tune``) is an output: SQLite files inside the output folder, given
    explicitly (the command's default file lies in the working directory)."""
    dest = next((d for d, a in settable.items() if path_role(a) == "storage"), None)
    if dest is None:
        return
    url = getattr(step.args, dest)
    if url is None:
        raise InputError(f"{where}: give option {dest!r}, e.g. \"{SQLITE}{{out}}/optuna.db\": "
                         "the default storage lies outside the experiment's output folder",
                         file=path)
    if url.startswith(SQLITE):
        db = Path(os.path.realpath(out / url[len(SQLITE):]))
        if not inside(db, out):
            raise InputError(f"{where}: option {dest!r}: {url!r} lies outside the experiment's "
                             f"output folder {out}", file=path)
        step.outputs.append(db)
        setattr(step.args, dest, f"{SQLITE}{db}")


def inside(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies below it (both already resolved)."""
    return path == folder or folder in path.parents


def _argv(action: argparse.Action, value) -> list[str]:
    if action.nargs == 0:
        return [action.option_strings[0]] if value == action.const else []
    words = [str(v) for v in value] if isinstance(value, list) else [str(value)]
    return [action.option_strings[0], *words] if action.option_strings else words


def _check_keys(table: dict, allowed: tuple, what: str, path: Path, *, where: str = "",
                hint: str = "") -> None:
    unknown = [k for k in table if k not in allowed]
    if unknown:
        raise InputError(f"{where}unknown {what} {unknown[0]!r}; expected "
                         f"{', '.join(allowed)}{hint}", file=path)


def _kind(value) -> str:
    names = {bool: "a boolean", int: "an integer", float: "a float", str: "a string",
             list: "an array", dict: "a table"}
    return names.get(type(value), type(value).__name__)


# --------------------------------------------------------------------------- running
def execute(experiment: Experiment) -> int:
    """Run every step in order; stop at the first failing step and return its exit code
    (3, an alert, does not stop the experiment)."""
    import mlflow

    from pipeline import tracking

    experiment.out.mkdir(parents=True, exist_ok=True)
    before = snapshot(experiment)
    known = commands()
    worst = 0
    with tracking.run("experiments", experiment.name) as active:
        mlflow.log_artifact(str(experiment.path))
        try:
            for step in experiment.steps:
                code = run_step(step, known[step.command], len(experiment.steps))
                mlflow.log_metric(f"step_{step.index}_exit_code", code)
                if code not in (0, ALERT_EXIT):
                    print(f"step {step.index} failed with exit code {code}", file=sys.stderr)
                    return code
                worst = max(worst, code)
        finally:
            log_outputs(experiment, before)
        print(f"\nexperiment {experiment.name!r}: MLflow run {active.info.run_id} in "
              f"{tracking.tracking_uri()}; outputs in {experiment.out}/", file=sys.stderr)
    return worst


def run_step(step: Step, module, total: int) -> int:
    shown = shlex.join(_short(word) for word in step.argv)
    print(f"\n[{step.index}/{total}] {step.title}\n$ backlash {shown}", file=sys.stderr,
          flush=True)
    try:
        missing = [p for p in step.inputs if not p.exists()]
        if missing:
            raise InputError(f"step {step.index} ({step.command}): no such file or folder "
                             f"{str(missing[0])!r} (no earlier step wrote it)")
        created = check_outputs(step.command, step.args)
        try:
            return int(module.run(step.args) or 0)
        except (InputError, ValueError):
            remove_created(created)
            raise
    except (InputError, ValueError) as err:  # a user error, as the command line treats it
        line = err.line() if isinstance(err, InputError) else " ".join(str(err).split())
        print(f"backlash {step.command}: error: {line}", file=sys.stderr)
        return 2


def _short(word: str) -> str:
    """A path below the working directory as a relative path, for display."""
    if os.path.isabs(word) and inside(Path(word), Path.cwd().resolve()):
        return os.path.relpath(word)
    return word


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
    import mlflow

    for f in _files(experiment):
        if before.get(f) == _identity(f):
            continue
        folder = f.parent.relative_to(experiment.out).as_posix()
        mlflow.log_artifact(str(f), artifact_path="out" if folder == "." else f"out/{folder}")
