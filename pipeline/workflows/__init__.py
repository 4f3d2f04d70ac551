"""Workflows: one function per job, typed keyword parameters in, a result object out.

The CLI (``pipeline.commands``), experiment files (``pipeline.experiment``) and Python users
(``pipeline.api``) all call these functions. A workflow checks what it is given with
``check_params`` (scikit-learn's constraint language, the same as the estimators'
``_parameter_constraints``; ``pipeline.workflows.constraints`` speaks it without importing
scikit-learn), never prints (notes are ``BacklashWarning`` or result fields,
progress goes to the ``progress`` callback) and names Python parameters in its errors.
"""

from __future__ import annotations

from collections.abc import Mapping

from features.readings.errors import InputError


def check_params(constraints: dict, values: dict, caller: str) -> None:
    """Check keyword values against scikit-learn parameter constraints.

    Parameters
    ----------
    constraints : dict
        Parameter name -> list of constraints (``Interval``, ``StrOptions``, types,
        ``"array-like"``, ``None``...), as in scikit-learn's ``_parameter_constraints``; those
        of ``pipeline.workflows.constraints`` are checked without importing scikit-learn.
    values : dict
        Parameter name -> value given.
    caller : str
        The workflow's name, shown in the message.

    Raises
    ------
    InputError
        Naming the first parameter that breaks its constraint, or that has none (no name is
        skipped); ``.parameter`` is its name.
    """
    from pipeline.workflows import constraints as light

    for name, value in values.items():
        if name not in constraints:  # never skipped: a parameter without a constraint
            raise InputError(f"is not a parameter of {caller}; expected one of "
                             f"{', '.join(constraints)}", parameter=name)
        given = list(getattr(constraints[name], "accepts", constraints[name]))  # a Param's
        if isinstance(value, bool) and not light.takes_bool(given):
            message = light.must_be(given, value, name, caller)
        elif light.understood(given):
            message = light.violation(given, value, name, caller)
        else:
            message = _sklearn_violation(given, value, name, caller)
        if message is not None:
            raise InputError(_constraint_text(message, name), parameter=name)


def _sklearn_violation(given: list, value, name: str, caller: str) -> str | None:
    """scikit-learn's message for ``value`` breaking ``given``, or None when it meets them."""
    from sklearn.utils._param_validation import (
        InvalidParameterError,
        validate_parameter_constraints,
    )

    try:
        validate_parameter_constraints({name: given}, {name: value}, caller)
    except InvalidParameterError as err:
        return str(err)
    return None


def _constraint_text(message: str, name: str) -> str:
    """scikit-learn says "The 'x' parameter of f must be A. Got B instead."; the error already
    names the parameter, so keep "must be A; got B"."""
    _, _, rest = message.partition(" must be ")
    if not rest:
        return message
    expected, _, got = rest.rpartition(". Got ")
    return f"must be {expected}; got {got.removesuffix(' instead.')}" if got else f"must be {rest}"


class Constraints(Mapping):
    """A workflow's ``PARAMETERS``: parameter name -> constraints, built by ``build()`` on
    first use. Importing scikit-learn's constraint classes costs about a second, and every
    command imports its workflow just to show ``--help``."""

    def __init__(self, build):
        self._build = build
        self._table = None

    def _built(self) -> dict:
        if self._table is None:
            self._table = self._build()
        return self._table

    def __getitem__(self, name):
        return self._built()[name]

    def __iter__(self):
        return iter(self._built())

    def __len__(self):
        return len(self._built())


def readings_data() -> list:
    """The constraint of a workflow's readings ``data``: a readings file or a fleet store (a
    path or a ``postgresql://`` URL), or a readings frame."""
    import os

    import pandas as pd

    return [str, os.PathLike, pd.DataFrame]


def each_once(names: list, parameter: str) -> list:
    """``names`` unchanged when none is given twice; else an InputError naming ``parameter``."""
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise InputError(f"names {duplicated[0]!r} twice", parameter=parameter)
    return names


def readings_of(data, format: str = "auto", parameter: str = "data", selection=None,
                options: dict | None = None):
    """The validated readings frame a workflow works on.

    Parameters
    ----------
    data : str, path-like or DataFrame
        A readings file (read in ``format``), a fleet store (a store folder or a
        ``postgresql://`` URL: ``pipeline.store``) or a frame as ``read`` returns it (checked,
        not re-read).
    format : str
        Layout of a readings file (``"auto"``: detect); a store takes only ``"auto"``.
    parameter : str
        The caller's parameter that passed ``data`` (named in errors).
    selection : features.readings.selection.Selection, optional
        Keep only these tests (a store reads only what it may keep).
    options : dict, optional
        Options of a raw log's reader (``channels``, ``reference_scale``: the ``camonitor``
        layout); only a file of that layout takes them.
    """
    import os

    from features.readings.selection import Selection

    selection = selection or Selection()
    if isinstance(data, (str, os.PathLike)):
        from pipeline.store import is_store, open_store

        if is_store(data) or os.path.isdir(data):
            _no_options(options, data)
            if format != "auto":
                raise InputError(f"is {format!r}, but a fleet store holds validated readings; "
                                 "expected 'auto'", parameter="format")
            return open_store(data).read(selection)
        from features.readings.io import read_readings

        frame = read_readings(data, format, **(options or {}))
    else:
        from features.readings.validation import check_readings

        _no_options(options, parameter)
        frame = check_readings(data, parameter)
    return selection.apply(frame, frame.attrs.get("source", parameter))


def _no_options(options: dict | None, source) -> None:
    """A store or a frame holds readings already: a raw log's options do not apply."""
    given = [name for name, value in (options or {}).items() if value is not None]
    if given:
        raise InputError(f"applies to a raw log (--format camonitor) only; {source} holds "
                         "readings", parameter=given[0])


def source_of(data, readings) -> str:
    """The name a result gives its data: the path or store as given (a store URL without its
    password), or the frame's ``attrs["source"]``."""
    import os

    if isinstance(data, (str, os.PathLike)):
        from pipeline.store import redact

        return redact(data)
    return readings.attrs.get("source", "readings")


# --------------------------------------------------------------------------- the registry
import importlib
from dataclasses import dataclass

# Every job, in the order the CLI lists it; ``pipeline.workflows.<module>`` defines ``WORKFLOW``.
NAMES = ("convert", "ingest", "store", "void", "iso", "targets", "report", "simulate", "train", "predict", "compare", "tune", "rank",
         "replicate", "drift", "fleet", "discover", "hidden-effects", "compensate",
         "uncertainty", "volumetric", "circle", "monitor")


@dataclass(frozen=True)
class Workflow:
    """One job's record: the CLI command, the experiment runner and the docs read it.

    Attributes
    ----------
    name : str
        The job's name, also its CLI command and an experiment step's ``job``.
    function : callable
        ``function(**parameters, progress=None) -> Result``.
    summary : str
        One sentence: the command's help and the docs' table of jobs.
    inputs : tuple of str
        Parameters that name files or folders to read (an experiment resolves them against
        its own folder and checks they exist).
    tracked : bool
        The result is logged to MLflow (``tracking_record``) when the runner tracks
        (``pipeline.runner``).
    """

    name: str
    function: object
    summary: str
    inputs: tuple[str, ...] = ()
    tracked: bool = False

    @property
    def parameters(self) -> Mapping:
        """The job's parameter table (``PARAMETERS`` of its module:
        ``pipeline.workflows.parameters``): the runner checks calls against it, the CLI
        generates its options from it."""
        return importlib.import_module(f"pipeline.workflows.{self.name.replace('-', '_')}"
                                       ).PARAMETERS


def workflow(name: str) -> Workflow:
    """The record of job ``name`` (imports its module on first use)."""
    if name not in NAMES:
        raise InputError(f"unknown job {name!r}; expected one of {', '.join(NAMES)}",
                         parameter="name")
    return importlib.import_module(f"pipeline.workflows.{name.replace('-', '_')}").WORKFLOW
