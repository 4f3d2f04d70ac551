"""``run_job``: how every command runs its job through the one runner (``pipeline.runner``),
with the parameters its options give (``given``, by the job's parameter table) and the test
selection (``selected``: one option per record of ``features.readings.selection.FILTERS``)."""

from __future__ import annotations

from features.readings.selection import FILTERS
from pipeline.commands.common import parse_list


def run_job(job: str, args, progress: str | None = None, **params):
    """Run ``job`` through the one runner (``pipeline.runner.run``) with ``params``, the test
    selection given on the command line (``--machine``, ``--axis``, ``--since``, ``--until``)
    and ``--no-track``; ``progress`` names a progress bar to draw."""
    from pipeline.runner import run
    from pipeline.workflows import workflow

    own = tuple(workflow(job).parameters)  # a filter the job declares comes as its table says
    params = {**selected(args, skip=own), **given(job, args), **params}
    params["track"] = not getattr(args, "no_track", False)
    if progress is None:
        return run(job, **params)
    from pipeline.commands.common import progress_bar

    with progress_bar(progress) as bar:
        return run(job, progress=bar, **params)


def given(job: str, args) -> dict:
    """The job's parameters as the command line gave them (``add_parameters`` declared them
    from its table), by Python name: every one, its default where not given."""
    from pipeline.workflows import workflow

    params = {}
    for name, param in workflow(job).parameters.items():
        if param.on_cli and hasattr(args, name):
            value = getattr(args, name)
            params[name] = one_or_all(value) if param.nargs and value is not None else value
    return params


def one_or_all(inputs: list):
    """An argument that takes several inputs (``nargs="+"``) as the workflow takes it: the
    one input, or the list."""
    return inputs[0] if len(inputs) == 1 else inputs


def selected(args, skip: tuple[str, ...] = ()) -> dict:
    """The filters given on the command line (comma lists parsed), by Python parameter."""
    given = {f.name: getattr(args, f.name, None) for f in FILTERS if f.name not in skip}
    for name in ("machine", "axis"):
        if given.get(name) is not None:
            given[name] = parse_list(given[name], name)
    return {name: value for name, value in given.items() if value is not None}
