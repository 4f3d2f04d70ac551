"""The ``backlash`` CLI: one module per subcommand with ``add_arguments(parser)`` (the job's
options, generated from its parameter table by ``parameters.add_parameters``, plus the
command's own: ``--json``, a plot) and ``run(args) -> int`` (``data.run_job``, then print).
A command's summary is its job's record (``pipeline.workflows.WORKFLOWS``); its own options
that name an output or a Python parameter may be listed in ``OUTPUTS`` (checked before any
work) and ``FLAGS``. A command parses, calls the runner, prints or writes its result."""

from pipeline.workflows import NAMES as JOBS

# The one command registry: every job, then the experiment runner. Order is --help's order.
NAMES = (*JOBS, "run")
