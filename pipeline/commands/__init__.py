"""The ``backlash`` CLI: one module per subcommand, each ``HELP``, ``OUTPUTS`` (output paths by
argparse dest, checked before any work), optional ``FLAGS`` (Python parameter -> option, where it
is not ``--name``), ``add_arguments(parser)`` and ``run(args) -> int``. A command parses, calls a
workflow (``pipeline.workflows``), prints or writes its result."""

from pipeline.workflows import NAMES as JOBS

# The one command registry: every job, then the experiment runner. Order is --help's order.
NAMES = (*JOBS, "run")
