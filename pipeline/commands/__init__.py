"""The ``backlash`` CLI: one module per subcommand with ``add_arguments(parser)`` (the job's
options, generated from its parameter table by ``parameters.add_parameters``, plus the
command's own: ``--json``, a plot) and ``run(args) -> int`` (``data.run_job``, then print).
A command's summary is its job's record (``pipeline.workflows.WORKFLOWS``); its own options
that name an output or a Python parameter may be listed in ``OUTPUTS`` (checked before any
work) and ``FLAGS``. A command parses, calls the runner, prints or writes its result."""

import importlib

import pipeline.workflows as jobs


def names() -> tuple[str, ...]:
    """The one command registry: every job, then the experiment runner, in --help's order
    (read from the job records when asked, so a job added by ``register`` has its command)."""
    return (*jobs.NAMES, "run")


def __getattr__(name: str):
    if name == "NAMES":
        return names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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


def synopsis(name: str) -> str:
    """How command ``name`` is called, in short: its positional arguments and required options
    (from its job's table), then ``[options]``; a command module may say it itself
    (``SYNOPSIS``)."""
    from pipeline.workflows import workflow

    own = getattr(command_of(name), "SYNOPSIS", None)
    if own is not None:
        return own
    words = [f"backlash {name}"]
    for option, param in workflow(name).parameters.items():
        if param.on_cli and param.positional:
            words.append(param.flag + ("..." if param.nargs else ""))
        elif param.on_cli and param.required:
            words.append(f"{param.option(option)} {param.metavar or option.upper()}")
    return " ".join(words) + " [options]"


def commands_table() -> str:
    """The docs' table of commands (``docs/index.md``, filled in by ``docs/hooks.py`` as the
    site is built): per job its synopsis, its record's summary and its page."""
    from pipeline.workflows import WORKFLOWS

    rows = ["| command | does |", "|---|---|"]
    rows += [f"| `{synopsis(w.name).replace('|', chr(92) + '|')}` | {w.summary} "
             f"[more]({w.name}.md) |" for w in WORKFLOWS]
    return "\n".join(rows)
