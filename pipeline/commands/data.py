"""The DATA of every command that reads readings: a readings file or a fleet store, ``--format``
and the test filters (one option per record of ``features.readings.selection.FILTERS``),
declared here once; the data options of the model commands (train, compare, tune); and
``run_job``, how every command runs its job with them (``pipeline.runner``)."""

from __future__ import annotations

import argparse

from features.readings.schema import DATA_HELP
from features.readings.selection import FILTERS
from pipeline.commands.common import FORMATS, parse_features, parse_list

STORE_HELP = "; or a fleet store: a folder or a postgresql:// URL (backlash ingest)"
# The help of every readings argument that lists the layouts: generated from their records.
READINGS_HELP = DATA_HELP + STORE_HELP


def add_readings_argument(parser: argparse.ArgumentParser, dest: str = "data",
                          help: str | None = None, metavar: str | None = None,
                          skip: tuple[str, ...] = (), nargs: str | None = None) -> None:
    """DATA (a readings file or a fleet store; several with ``nargs="+"``), ``--format`` and
    one option per test filter (except ``skip``): every command that reads readings declares
    them here, so their choices and help are the same everywhere."""
    parser.add_argument(dest, metavar=metavar, nargs=nargs,
                        help=READINGS_HELP if help is None else help + STORE_HELP)
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout of a file (default: detect)")
    group = parser.add_argument_group("test selection (a store or a file)")
    for f in FILTERS:
        if f.name not in skip:
            group.add_argument(f"--{f.name}", metavar=f.metavar, help=f.help)


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
        if getattr(param, "on_cli", False) and hasattr(args, name):
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


def add_target_argument(parser: argparse.ArgumentParser) -> None:
    """``--target``: which backlash definition the points use (``features.targets``)."""
    parser.add_argument("--target", default="auto", choices=("auto", "paper", "iso"),
                        help="backlash definition: pendulum minus linear (paper), ISO reversal "
                             "value (iso) or chosen from the measuring-system evidence (auto)")


def add_data_arguments(parser: argparse.ArgumentParser) -> None:
    """DATA and the options of the model commands (train, compare, tune)."""
    add_readings_argument(parser)
    add_target_argument(parser)
    parser.add_argument("--features", help="comma-separated feature-table columns (default: the "
                                           "paper's inputs the data supply, plus dwell_s and "
                                           "operating_hours)")
    parser.add_argument("--split", default="random", choices=("random", "forward"),
                        help="hold-out: random 15 %% (paper) or the later visits (forward)")
    parser.add_argument("--truth", metavar="FILE",
                        help="twin truth table (backlash simulate): also score against the "
                             "true backlash")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def data_params(args) -> dict:
    """The keyword parameters of ``add_data_arguments`` for a model workflow (train, compare,
    backtest, tune), the comma lists parsed."""
    return {"format": args.format, "target": args.target,
            "features": parse_features(args.features), "truth": args.truth,
            "seed": args.seed}
