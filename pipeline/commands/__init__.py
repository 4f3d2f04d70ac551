"""The ``backlash`` CLI: one module per subcommand with ``add_arguments(parser)`` (the job's
options, generated from its parameter table by ``parameters.add_parameters``, plus the
command's own: ``--json``, a plot) and ``run(args) -> int`` (``data.run_job``, then print).
A command's summary is its job's record (``pipeline.workflows.WORKFLOWS``); its own options
that name an output or a Python parameter may be listed in ``OUTPUTS`` (checked before any
work) and ``FLAGS``. A command parses, calls the runner, prints or writes its result."""

import importlib

from pipeline.workflows import NAMES as JOBS

# The one command registry: every job, then the experiment runner. Order is --help's order.
NAMES = (*JOBS, "run")


def command_of(name: str):
    """Command ``name``'s module (``pipeline.commands.<name>``), or for a job without one the
    default command (``pipeline.commands.default``)."""
    module = f"pipeline.commands.{name.replace('-', '_')}"
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name != module:
            raise
    from pipeline.commands.default import command

    return command(name)
