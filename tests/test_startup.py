"""``backlash --help`` and ``backlash CMD --help`` load no numeric library: the parser is built
from light modules, and a job's heavy modules load when it runs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.commands import NAMES

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pandas", "scipy", "sklearn", "torch", "mlflow", "optuna", "matplotlib",
         "pyarrow")
CODE = """
import contextlib, io, sys
from pipeline.cli import main
with contextlib.redirect_stdout(io.StringIO()) as text:
    code = main(sys.argv[1:])
heavy = sorted(h for h in {heavy!r} if h in sys.modules)
print(code, len(text.getvalue().splitlines()) > 3, ",".join(heavy) or "-")
"""


def help_of(*argv: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", CODE.format(heavy=HEAVY), *argv],
                          capture_output=True, text=True, check=True, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    return done.stdout.split()


def test_the_help_imports_no_numeric_library():
    assert help_of("--help") == ["0", "True", "-"]


@pytest.mark.parametrize("command", ["iso", "train", "compensate", "fleet", "circle", "run"])
def test_a_commands_help_imports_no_numeric_library(command):
    assert command in NAMES
    assert help_of(command, "--help") == ["0", "True", "-"]


def test_running_a_job_does_load_them(tmp_path):
    """The check above can fail: a job that runs imports pandas."""
    data = REPO / "experiments" / "data" / "ecmc" / "ess_mcu1025_ISO230.dat"
    code, _, heavy = help_of("iso", str(data))
    assert code == "0" and "pandas" in heavy.split(",")
