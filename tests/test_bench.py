"""Every benchmark module runs to the end at tiny sizes (``BACKLASH_BENCH_TINY=1``), prints its
figures and no warning: ``make bench`` is run by hand, so a benchmark that no longer runs would
otherwise go unseen until someone needs its figures."""

from __future__ import annotations

import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "bench"
# found as ``python -m bench`` finds them, so a new module is covered without a change here
MODULES = sorted(m.name.removeprefix("bench_") for m in pkgutil.iter_modules([str(BENCH)])
                 if m.name.startswith("bench_"))


@pytest.fixture(autouse=True)
def _isolated_tracking():
    """No per-test MLflow store (its template costs a minute on a loaded machine): a bench
    whose commands track gives them a temporary folder of its own."""


def test_modules_found():
    assert len(MODULES) >= 10, MODULES


@pytest.mark.parametrize("name", MODULES)
def test_bench_runs_tiny(name, tmp_path):
    env = {**os.environ, "BACKLASH_BENCH_TINY": "1", "MLFLOW_DISABLE_TELEMETRY": "true",
           "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    env.pop("PYTHONWARNINGS", None)  # the warnings a user of ``make bench`` would see
    # the working directory is a fresh folder, so a bench writing beside the user's files shows
    done = subprocess.run([sys.executable, "-m", "bench", name], cwd=tmp_path, env=env,
                          check=False, capture_output=True, text=True, timeout=600)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-4000:]
    lines = done.stdout.splitlines()
    assert lines[:2] == ["tiny run: figures not a measurement", f"== {name}"], output[-4000:]
    assert any(line.strip() for line in lines[2:]), f"{name} printed no figures"
    assert "Warning" not in output, output[-4000:]
    assert not list(tmp_path.iterdir()), f"{name} wrote into the working directory"
