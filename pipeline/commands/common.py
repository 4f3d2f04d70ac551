"""What the commands share: comma lists, output checks and the progress bar (the checked option
types are in ``options``, the options generated from a job's table in ``parameters``, how a
command runs its job in ``data``)."""

from __future__ import annotations

import contextlib
import shutil
import sys
from pathlib import Path

from features.readings.errors import InputError


def parse_list(text: str | None, parameter: str) -> list[str] | None:
    """A comma-separated option as a list of names (None when not given)."""
    from pipeline.steps.parameters import each_once

    if text is None:
        return None
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names:
        raise InputError("is empty; give comma-separated names", parameter=parameter)
    return each_once(names, parameter)


def check_outputs(command: str, module, args) -> list[Path]:
    """Refuse output paths that cannot work before any work is done (the job's table's, and
    ``OUTPUTS`` of its command ``module``); return the folders this run will create (removed
    again if the run ends in a user error)."""
    from features.readings.fileio import check_output

    outputs = {dest: (kind, f"--{dest.replace('_', '-')}")
               for dest, kind in getattr(module, "OUTPUTS", {}).items()}
    for name, param in _table(command).items():
        if param.output is not None:
            outputs[name] = (param.output, param.option(name))
    created = []
    for dest, (kind, option) in outputs.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        root = check_output(value, kind, option)
        if root is not None:
            created.append(root)
    return created


def _table(command: str) -> dict:
    """A job's parameter table (``pipeline.steps.parameters``); the experiment runner's
    command has none."""
    from pipeline.workflows import NAMES, workflow

    return dict(workflow(command).parameters) if command in NAMES else {}


def option_names(command: str, module) -> dict:
    """Python parameter -> the option or argument that gives it on the command line: from the
    job's table, and its command ``module``'s own ``FLAGS`` (its options that are no job
    parameter)."""
    names = {name: param.option(name) for name, param in _table(command).items()}
    return {**names, **getattr(module, "FLAGS", {})}


@contextlib.contextmanager
def progress_bar(what: str = ""):
    """A ``progress(done, total, what)`` callback drawing a tqdm bar on stderr (only when
    stderr is a terminal: logs and pipes stay clean)."""
    from tqdm import tqdm

    bar = tqdm(desc=what, disable=not sys.stderr.isatty(), leave=False, file=sys.stderr)

    def progress(done: int, total: int, step: str = "") -> None:
        if total and bar.total != total:
            bar.total = total
        if step:
            bar.set_postfix_str(step, refresh=False)
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        bar.close()


def remove_created(folders: list[Path]) -> None:
    for folder in folders:
        shutil.rmtree(folder, ignore_errors=True)


def show(result, args, table) -> int:
    """Print a result as a command with a table of its own does: its JSON with ``--json``,
    else ``table(json)``; what it recorded and wrote on stderr."""
    from features.readings.fileio import dumps

    document = result.to_dict()
    print(dumps(document) if args.json else table(document))
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.out:
        print(f"wrote {len(result.files)} files to {args.out}", file=sys.stderr)
    return 0
