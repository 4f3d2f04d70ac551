"""``backlash run``: run a declarative experiment file and log it to MLflow."""

from __future__ import annotations

import argparse

HELP = ("Run an experiment file (TOML steps: a command and its options each) and log it to "
        "MLflow.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="experiment file, e.g. experiments/demo.toml")
    parser.add_argument("--out", help="output folder (default: the file's `out`); relative to "
                                      "the working directory")


def run(args: argparse.Namespace) -> int:
    from pipeline import experiment

    return experiment.execute(experiment.load(args.file, args.out))
