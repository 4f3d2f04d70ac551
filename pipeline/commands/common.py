"""Arguments and loading steps shared by the model commands (train, compare, tune)."""

from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
from pathlib import Path

from features.readings import schema
from features.readings.errors import InputError

FORMATS = schema.FORMATS  # the input layouts every --format option offers


def add_data_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="readings file: CSV, Parquet, paper Table-2 CSV or ecmc .dat")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")
    parser.add_argument("--target", default="auto", choices=("auto", "paper", "iso"),
                        help="backlash definition: pendulum minus linear (paper), ISO reversal "
                             "value (iso) or chosen from the measuring-system evidence (auto)")
    parser.add_argument("--features", help="comma-separated feature-table columns (default: the "
                                           "paper's inputs the data supply, plus dwell_s and "
                                           "operating_hours)")
    parser.add_argument("--split", default="random", choices=("random", "forward"),
                        help="hold-out: random 15 %% (paper) or the later visits (forward)")
    parser.add_argument("--truth", metavar="FILE",
                        help="twin truth table (backlash simulate): also score against the "
                             "true backlash")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def parse_features(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names:
        raise InputError("--features is empty; give comma-separated column names")
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise InputError(f"--features names {duplicated[0]!r} twice")
    return names


def load_table(args):
    """Readings -> feature table (validated), noise floor of one target, and the truth table."""
    from features.readings import read_readings
    from features.table import check_features, feature_table
    from models.evaluation import target_noise_floor

    readings = read_readings(args.data, args.format)
    table = feature_table(readings, target=args.target, features=parse_features(args.features))
    check_features(table.X, str(args.data))
    truth = read_truth(args.truth) if args.truth else None
    return readings, table, target_noise_floor(readings, table.target_kind), truth


def read_truth(path):
    import pandas as pd

    try:
        truth = pd.read_csv(path, dtype={"visit": str, "machine_id": str, "axis": str})
    except FileNotFoundError:
        raise InputError("cannot read truth table: no such file", file=path) from None
    except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as err:
        raise InputError(f"cannot read truth table: {err}", file=path) from None
    if "true_backlash_um" not in truth:
        raise InputError("missing column true_backlash_um: expected the truth table written "
                         "by backlash simulate", file=path, column="true_backlash_um")
    return truth


# --------------------------------------------------------------------------- option values

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
    value = _whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 1")
    return value


def zero_or_more(text: str) -> int:
    """An integer option where 0 means "none" (e.g. bootstrap resamples): a whole number >= 0."""
    value = _whole(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 0")
    return value


def seed(text: str) -> int:
    """A random seed: a whole number from 0 to 2**32 - 1."""
    value = _whole(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a seed from 0 to {MAX_SEED}")
    return value


def _whole(text: str) -> int:
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


def check_outputs(command: str, args) -> list[Path]:
    """Refuse output paths that cannot work before any work is done; return the folders
    this run will create (removed again if the run ends in a user error)."""
    from features.readings.fileio import check_output

    import importlib

    module = importlib.import_module(f"pipeline.commands.{command.replace('-', '_')}")
    created = []
    for dest, kind in getattr(module, "OUTPUTS", {}).items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        root = check_output(value, kind, f"--{dest.replace('_', '-')}")
        if root is not None:
            created.append(root)
    return created


@contextlib.contextmanager
def progress_bar(what: str = ""):
    """A ``progress(done, total, what)`` callback drawing a tqdm bar on stderr (only when
    stderr is a terminal: logs and pipes stay clean)."""
    from tqdm import tqdm

    bar = tqdm(desc=what, disable=not sys.stderr.isatty(), leave=False, file=sys.stderr)

    def progress(done: int, total: int, step: str = "") -> None:
        if total and bar.total != total:
            bar.total = total
        if step:
            bar.set_postfix_str(step, refresh=False)
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        bar.close()


def remove_created(folders: list[Path]) -> None:
    for folder in folders:
        shutil.rmtree(folder, ignore_errors=True)
