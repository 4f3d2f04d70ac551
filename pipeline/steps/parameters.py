"""One table per job: what each parameter accepts, and how the command line spells it.

A job's ``PARAMETERS`` maps every Python parameter of its workflow to a ``Param``. The same
table does two things, so that a parameter means the same wherever it is given:

* the runner checks every call against it (``check_params``: the
  signature bound, exact names, the constraints of scikit-learn's ``_parameter_constraints``);
* the CLI generates the job's options from it (``pipeline.commands.parameters.add_parameters``):
  the option's name, type, choices, default (the workflow's own, from its signature) and
  help; ``run_job`` hands every option back to the runner under its Python name.

A parameter is described once, in the workflow function's numpydoc ``Parameters`` section:
the option's help and the docs' table take it from there (``helps``) unless its ``Param``
gives a help of its own. Its default is the signature's. A type that lives in a heavy module
is named by its dotted path (``"pandas.DataFrame"``) and imported only when a value is checked.
"""

from __future__ import annotations

import datetime as dt
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from numbers import Integral, Real

from features.readings.errors import InputError
from pipeline.steps.constraints import HasMethods, Interval, StrOptions


@dataclass(frozen=True)
class Param:
    """One parameter of a job.

    Attributes
    ----------
    accepts : tuple
        The values it takes: constraints in scikit-learn's language (types, None,
        ``"boolean"``, ``Interval``, ``StrOptions``...: ``pipeline.steps.constraints``'s
        declarations, scikit-learn's objects once a value is checked; a heavy type by its
        dotted name).
    help : str or None
        The option's help; None: the parameter's description in the workflow function's
        numpydoc ``Parameters`` section (``helps``).
    flag : str or None
        The option, when not ``--name-with-dashes``; a name without a leading dash (``"FILE"``)
        makes it the command's positional argument, shown by that name.
    metavar : str or None
        The option's value in the help.
    nargs : str or None
        ``"+"``: one or more values (a positional argument given several files); one value
        reaches the workflow as itself, several as a list.
    parse : callable or None
        The option's text to the value (``argparse``'s ``type``); default: from ``accepts``
        (a number checked by scikit-learn against its ``Interval``, else the text, never empty).
    choices : tuple or None
        The values the option offers, in order; default: a ``StrOptions``'s.
    required : bool
        The command line must give it (a Python call may leave it to the default).
    output : {"file", "folder"} or None
        An output path, checked before any work (a folder the run creates is removed if it ends
        in a user error).
    group : str or None
        The title of the help section it is listed under.
    repeated : bool
        The option may be given several times, one value each; the values reach the workflow
        as a list.
    reads_readings : bool
        The job's readings (``readings()``): the command line adds the test selection
        (``--machine``, ``--axis``, ``--since``, ``--until``) the job does not declare itself.
    cli : bool
        False: a Python-only parameter (a frame, a model object, a callback), not on the
        command line (``python_only``).
    """

    accepts: tuple
    help: str | None = None
    flag: str | None = None
    metavar: str | None = None
    nargs: str | None = None
    parse: Callable[[str], object] | None = None
    choices: tuple | None = None
    required: bool = False
    output: str | None = None
    group: str | None = None
    repeated: bool = False
    reads_readings: bool = False
    cli: bool = True

    @property
    def on_cli(self) -> bool:
        return self.cli

    @property
    def positional(self) -> bool:
        return self.flag is not None and not self.flag.startswith("-")

    def option(self, name: str) -> str:
        """How the command line names it: ``--plot``, ``--name-with-dashes`` or ``FILE``."""
        return self.flag or f"--{name.replace('_', '-')}"


def python_only(*accepts) -> Param:
    """A parameter only a Python call gives (a frame, a model object, a callback)."""
    return Param(tuple(accepts), cli=False)


def helps(function, table) -> dict[str, str]:
    """Python name -> help of every command-line parameter of ``table`` (a job's
    ``PARAMETERS``): its ``Param.help``, else its description in ``function``'s numpydoc
    ``Parameters`` section as plain text (``pipeline.steps.docstrings``; "" when neither
    describes it; ``tests/test_parameters_docs.py`` checks that every job's do)."""
    from pipeline.steps.docstrings import parameter_descriptions, plain

    described = parameter_descriptions(function)
    return {name: plain(described.get(name, "")) if param.help is None else param.help
            for name, param in table.items() if param.on_cli}


def comma_list(text: str) -> list[str]:
    """A comma list of names (``"X,Y"``) as the list; an empty one, or a name given twice, is
    refused."""
    import argparse

    listed = [p.strip() for p in text.split(",") if p.strip()]
    if not listed:
        raise argparse.ArgumentTypeError("is empty; give comma-separated names")
    twice = sorted({n for n in listed if listed.count(n) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"names {twice[0]!r} twice")
    return listed


def each_once(names: list, parameter: str) -> list:
    """``names`` unchanged when none is given twice; else an InputError naming ``parameter``."""
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise InputError(f"names {duplicated[0]!r} twice", parameter=parameter)
    return names


def scale_offset(text: str) -> tuple[float, float]:
    """``SCALE`` or ``SCALE,OFFSET`` (finite numbers, SCALE not 0) as the pair."""
    import argparse

    try:
        numbers = [float(p) for p in text.split(",")]
    except ValueError:
        numbers = []
    if not 1 <= len(numbers) <= 2 or not all(map(math.isfinite, numbers)) or numbers[0] == 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected SCALE or SCALE,OFFSET (finite "
                                         "numbers, SCALE not 0)")
    return numbers[0], numbers[1] if len(numbers) > 1 else 0.0


RAW_LOG_GROUP = "a raw log (--format camonitor)"  # the help section of a raw log's reader
# A raw log's reader options (features.readings.approaches): the jobs that read readings from
# a raw ISO 230-2 log declare them; the runner hands them to the reader when the workflow
# does not take them itself.
RAW_LOG = {
    "channels": Param((str, dict, None), "PVs of the set point, the reference, ecmc's test "
                      "number and the motor side: target=PV,reference=PV[,test=PV][,motor=PV] "
                      "(default: from ecmc's PV names)", metavar="NAME=PV,...",
                      group=RAW_LOG_GROUP),
    "reference_scale": Param((Real, tuple, list, None), "axis position = SCALE * reference + "
                             "OFFSET, in the set point's unit, as ecmc's gear ratio and offset "
                             "(negative allowed; default: fitted to the set points, reported "
                             "in a note)", metavar="SCALE[,OFFSET]", parse=scale_offset,
                             group=RAW_LOG_GROUP),
    "unit": Param((StrOptions(("mm", "um", "deg")), None), "unit of the set point (default: "
                  "deg when its PV names an axis A, B or C, else mm)", group=RAW_LOG_GROUP),
}


# --------------------------------------------------------------- parameters many jobs share
def _format() -> Param:
    from features.readings.schema import FORMATS

    return Param((StrOptions(tuple(FORMATS)),), "input layout of a file (default: detect)")


READINGS = (str, os.PathLike, "pandas.DataFrame")  # a file, a fleet store or a frame
SELECTION_GROUP = "test selection (a store or a file)"  # the help section of the filters
STORE_HELP = "; or a fleet store: a folder or a postgresql:// URL (backlash ingest)"


def readings(help: str | None = None, flag: str = "DATA", accepts: tuple = READINGS,
             nargs: str | None = None) -> Param:
    """The readings a job reads: a file in any layout (``features.readings.schema``'s help,
    else ``help``), a fleet store or a frame; on the command line its positional argument,
    followed by ``--format`` and the test selection."""
    from features.readings.schema import DATA_HELP

    return Param(accepts, (DATA_HELP if help is None else help) + STORE_HELP, flag=flag,
                 nargs=nargs, reads_readings=True)


FORMAT = _format()
PROGRESS = python_only(None, callable)
JSON_HELP = "print the result as JSON on stdout"

# the limits and the trend analysis of drift and fleet (models.condition.drift), in each axis's unit
_POSITIVE = Interval(Real, 0, None, closed="neither")
THRESHOLD_UM = Param((_POSITIVE, None), "backlash limit of the linear axes [um]: forecast the "
                     "date each crosses it", metavar="X")
THRESHOLD_ARCSEC = Param((_POSITIVE, None), "backlash limit of the rotary axes (A, B, C) "
                         "[arcsec]", metavar="X")
LIMITS = Param((str, os.PathLike, dict, None), "limits per machine and axis, each in its unit "
               "([M01] X_um = 8.0, C_arcsec = 40.0); other axes take --threshold-um/-arcsec",
               metavar="LIMITS.toml")
AS_OF = Param((str, dt.date, None), "compute the view as of this day (default today, UTC): "
              "tests started later are left out; overdue visits and limits passed since the "
              "last visit alert", metavar="YYYY-MM-DD")
WARN_MONTHS = Param((Interval(Real, 0, None, closed="left"),), "alert when the crossing may "
                    "come within this many months of the last visit")
ALPHA = Param((Interval(Real, 0, 0.5, closed="neither"),), "significance level of trend tests "
              "and intervals")
MIN_JUMP_SIGMA = Param((_POSITIVE,), "a change point must move the level by this many "
                       "standard errors")

BUDGET = (str, os.PathLike, dict, "features.uncertainty.UncertaintyBudget", None)  # ISO/TR 230-9
MODEL = (str, os.PathLike, HasMethods(["predict"]))  # a model directory or a trained predictor

# the fleet store a store job (void, store check) works on: its positional argument
STORE = Param((str, os.PathLike), "store folder or postgresql://USER@HOST/DB", flag="STORE")

# the backlash definition a job's points use (features.targets): targets and the model jobs
TARGET = Param((StrOptions(("auto", "paper", "iso")),), "backlash definition: pendulum minus "
               "linear (paper), ISO reversal value (iso) or chosen from the measuring-system "
               "evidence (auto)")

SEED = (Interval(Integral, 0, 2**32 - 1, closed="both"),)  # numpy's and torch's seed range


def parameters_table(function, table) -> str:
    """The Markdown table of a job's parameters for its docs page, generated from ``table``
    (its ``PARAMETERS``) and its workflow ``function``: the Python name, the command line's
    option (as ``pipeline.commands.parameters`` generates it), the default (``function``'s
    signature's) and the meaning (``helps``). ``docs/hooks.py`` puts it on the job's page at
    its ``<!-- parameters -->`` marker as the site is built, from the job's record."""
    import inspect

    signature = inspect.signature(function).parameters
    described = helps(function, table)
    rows = ["| Python | command line | default | meaning |", "|---|---|---|---|"]
    for name, param in table.items():
        if not param.on_cli:
            continue
        default = signature[name].default if name in signature else None
        shown = "" if default in (None, inspect.Parameter.empty) else f"`{_shown(default)}`"
        option = param.option(name)
        option = f"`{option}`" + (f" {param.metavar}" if param.metavar else "")
        # "[0, W] [mm]" would read as a Markdown reference link: the brackets are escaped
        meaning = described[name].replace("|", "/").replace("[", r"\[").replace("]", r"\]")
        rows.append(f"| `{name}` | {option} | {shown} | {meaning} |")
    return "\n".join(rows)


# the model data of train, compare, tune, rank, replicate (pipeline.steps.model_data)
SPLITS = ("random", "forward")  # compare adds its backtest
FEATURES = Param((list, tuple, None), "comma-separated feature-table columns (default: the "
                 "paper's inputs the data supply, plus dwell_s and operating_hours)", parse=comma_list)
SPLIT = Param((StrOptions(SPLITS),), "hold-out: random 15 % (paper) or the later visits "
              "(forward)")
TRUTH = Param((*READINGS, None), "twin truth table (backlash simulate): also score against the "
              "true backlash", metavar="FILE")
RANDOM_SEED = Param(SEED, "random seed")


def _shown(default) -> str:
    """A default as the docs show it: a path of the product relative to its folder (the same
    in every checkout), anything else as Python writes it."""
    if isinstance(default, os.PathLike):
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        return os.path.relpath(default, root)
    return repr(default)


# --------------------------------------------------------------- drift and fleet
# The one maintenance analysis drift and fleet share (models.condition.maintenance): the limits,
# the day it is computed as of and the trend analysis, each in the axis's unit. Both jobs' tables
# take the group whole; the meaning of each and its default are
# models.condition.settings.MaintenanceSettings's, which both signatures take their defaults from.
MAINTENANCE = {
    "threshold_um": THRESHOLD_UM,
    "threshold_arcsec": THRESHOLD_ARCSEC,
    "limits": LIMITS,
    "as_of": AS_OF,
    "warn_months": WARN_MONTHS,
    "alpha": ALPHA,
    "min_jump_sigma": MIN_JUMP_SIGMA,
}
