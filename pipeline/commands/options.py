"""Checked option types: every number, count, seed and text option of every command is
refused at parse time when it cannot mean anything (inf, nan, 0 resamples of a count, an
empty name), so a workflow never sees it."""

from __future__ import annotations

import argparse

MAX_SEED = 2**32 - 1  # numpy's and torch's seed range


def finite_float(text: str) -> float:
    """A float option: inf and nan are refused (they pass ``float`` but break every figure)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number")
    return value


def count(text: str) -> int:
    """An integer count option: a whole number >= 1."""
    value = whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 1")
    return value


def zero_or_more(text: str) -> int:
    """An integer option where 0 means "none" (e.g. bootstrap resamples): a whole number >= 0."""
    value = whole(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 0")
    return value


def seed(text: str) -> int:
    """A random seed: a whole number from 0 to 2**32 - 1."""
    value = whole(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a seed from 0 to {MAX_SEED}")
    return value


def whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None


def non_empty(text: str) -> str:
    """A text option or argument: an empty string is refused (it names no file, no model)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a value, got an empty string")
    return text


def checked_types(parser: argparse.ArgumentParser) -> None:
    """Give every plain ``float`` option ``finite_float``, every plain ``int`` option ``count``
    (or ``seed`` when its name ends in ``seed``) and every text option ``non_empty``; options
    with their own type keep it."""
    for action in parser._actions:
        if action.type is float:
            action.type = finite_float
        elif action.type is int:
            action.type = seed if action.dest.endswith("seed") else count
        elif action.type is None and isinstance(action, argparse._StoreAction):
            action.type = non_empty

