"""A job's options, generated from its parameter table (``pipeline.steps.parameters``):
the option's name, type, choices, default and help come from the table and the workflow's
signature and docstring, so a parameter means the same on the command line as in Python."""

from __future__ import annotations

import argparse

from pipeline.commands.options import count, finite_float, non_empty, seed, whole


def add_parameters(parser: argparse.ArgumentParser, job: str, skip: tuple[str, ...] = ()) -> None:
    """The options of job ``job``, generated from its parameter table (``Workflow.parameters``,
    ``pipeline.steps.parameters``): one per parameter the command line gives, with the
    workflow's own default; a job that reads readings also gets the test selection
    (``features.readings.selection.FILTERS``) it does not declare itself."""
    import inspect

    from features.readings.selection import FILTERS
    from pipeline.steps.parameters import SELECTION_GROUP, helps
    from pipeline.workflows import workflow

    record = workflow(job)
    signature = inspect.signature(record.function).parameters
    described = helps(record.function, record.parameters)  # the table's, else the docstring's
    groups: dict = {}
    for name, param in record.parameters.items():
        if not param.on_cli or name in skip:
            continue
        where = parser if param.group is None else _group(parser, groups, param.group)
        default = signature[name].default if name in signature else None
        default = None if default is inspect.Parameter.empty else default
        where.add_argument(*_names(name, param), **_keywords(name, param, default, described[name]))
        if param.reads_readings and SELECTION_GROUP not in groups:
            group = _group(parser, groups, SELECTION_GROUP)
            for f in FILTERS:
                if f.name not in record.parameters:
                    group.add_argument(f"--{f.name}", metavar=f.metavar, help=f.help)


def _group(parser, groups: dict, title: str):
    if title not in groups:
        groups[title] = parser.add_argument_group(title)
    return groups[title]


def _names(name: str, param) -> tuple[str, ...]:
    return (name,) if param.positional else (param.option(name),)


def _keywords(name: str, param, default, described: str) -> dict:
    """argparse's keywords for ``param``: a flag for a boolean, else a checked type."""
    from pipeline.steps.constraints import takes_bool

    # a required option has no default on the command line (the Python call's is not shown);
    # a help is plain text, not a format ("15 %")
    shown = "" if param.required else _default_text(described, default)
    help = described.replace("%", "%%") + shown
    if takes_bool(param.accepts) and not any(isinstance(c, type) and c is not bool
                                             for c in param.accepts):
        action = "store_true" if not default else argparse.BooleanOptionalAction
        return {"dest": name, "action": action, "default": bool(default), "help": help}
    keywords = {"help": help, "default": default, "type": param.parse or _parser(name, param)}
    if param.repeated:
        keywords["action"] = "append"
    if param.positional:
        keywords["metavar"] = param.flag
        if default is None:
            del keywords["default"]
    else:
        keywords.update(dest=name, metavar=param.metavar, required=param.required)
    choices = param.choices or _options(param.accepts)
    if choices is not None:
        keywords["choices"] = choices
    if param.nargs is not None:
        keywords["nargs"] = param.nargs
    return keywords


def _default_text(help: str, default) -> str:
    """`` (default X)`` after a help that does not say its default itself."""
    if default is None or default is False or "default" in help:
        return ""
    return f" (default {default:g})" if isinstance(default, float) else f" (default {default})"


def _options(accepts) -> tuple | None:
    """The choices of the first ``StrOptions`` declared, in its order (a set's sorted)."""
    from pipeline.steps.constraints import StrOptions

    return next((c.options for c in accepts if isinstance(c, StrOptions)), None)


def _parser(name: str, param):
    """The option's text to its value: a number of the declared interval's type, checked by
    scikit-learn's ``Interval`` (built when an option is parsed, never for ``--help``); else
    a count, a seed (by name) or a float for a parameter taking that type, or the text itself,
    never empty."""
    from numbers import Integral, Real

    from pipeline.steps.constraints import Interval

    declared = next((c for c in param.accepts if isinstance(c, Interval)), None)
    if declared is None:
        if int in param.accepts:
            return seed if name.endswith("seed") else count
        if float in param.accepts or Real in param.accepts:
            return finite_float
        return non_empty
    integral = declared.type is Integral

    def number(text: str):
        value = whole(text) if integral else finite_float(text)
        interval = declared.sklearn()
        if not interval.is_satisfied_by(value):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {interval}")
        return value

    number.__name__ = "int" if integral else "float"  # argparse names the type in its errors
    return number
