"""Readings files and helpers shared by the fleet-store tests (``test_ingest``, ``test_store``):
the twin's six visits of machine M01 axis X (one file per visit, copies for other machines),
a file of every accepted layout, a store's content as a comparable frame, and the CLI run in
a child process (optionally stalled at a chosen point, to be killed there)."""

from __future__ import annotations

import functools
import os
import select
import subprocess
import sys
from pathlib import Path

import pandas as pd

from features.readings.io import read_readings
from features.readings.rtl import write_rtl

REPO = Path(__file__).resolve().parents[1]
TWIN = REPO / "experiments" / "data" / "twin" / "readings.csv"
ECMC = REPO / "experiments" / "data" / "ecmc" / "ess_mcu1025_ISO230.dat"
KEYS = ["machine_id", "axis", "visit", "test_id"]


@functools.lru_cache(maxsize=1)
def _twin() -> pd.DataFrame:
    return read_readings(TWIN)


def twin() -> pd.DataFrame:
    """The twin's validated readings (a copy: callers may change it)."""
    return _twin().copy()


def visit_frame(visit: str, machine: str = "M01") -> pd.DataFrame:
    """One visit of the twin, its tests relabelled to ``machine``."""
    frame = twin()
    rows = frame[frame["visit"] == visit].reset_index(drop=True)
    return rows.assign(machine_id=machine, test_id=rows["test_id"].str.replace("M01", machine))


def visit_file(folder: Path, visit: str, machine: str = "M01", suffix: str = ".csv") -> Path:
    """One visit as a canonical CSV or Parquet file."""
    path = Path(folder) / f"{machine}_v{visit}{suffix}"
    frame = visit_frame(visit, machine)
    frame.to_parquet(path) if suffix == ".parquet" else frame.to_csv(path, index=False)
    return path


def visits(folder: Path, machine: str = "M01", which=("01", "02", "03", "04", "05", "06")):
    return [visit_file(folder, v, machine) for v in which]


def layout_files(folder: Path) -> dict[str, Path]:
    """One file of every accepted layout (canonical CSV and Parquet, paper, ecmc, rtl)."""
    folder = Path(folder)
    paper = folder / "table2.csv"
    pd.DataFrame({
        "Pos. [mm]": [0, 0, 100, 100], "Dev_lin_f [mm]": [-0.0012, -0.0010, 0.0031, 0.0033],
        "Dev_lin_r [mm]": [0.0011, 0.0012, 0.0052, 0.0050],
        "Dev_pend_f [mm]": [0.0008, 0.0009, 0.0040, 0.0041],
        "Dev_pend_r [mm]": [0.0021, 0.0022, 0.0060, 0.0062], "Speed [mm/min]": [500] * 4,
    }).to_csv(paper, index=False)
    test = visit_frame("01", "R07")
    test = test[test["test_id"] == test["test_id"].iloc[0]]
    rtl = write_rtl(test.assign(machine_id="R07"), folder / "laser.rtl")
    return {"canonical": visit_file(folder, "01"), "parquet": visit_file(folder, "02",
                                                                         suffix=".parquet"),
            "paper": paper, "ecmc": ECMC, "rtl": rtl}


def content(frame: pd.DataFrame) -> pd.DataFrame:
    """A readings frame in a form two reads of the same tests agree on (row order aside)."""
    columns = sorted(frame.columns)
    return (frame[columns].sort_values(KEYS + ["method", "target", "direction", "cycle"])
            .reset_index(drop=True))


def child_env(**extra) -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "MLFLOW_DISABLE_TELEMETRY": "true",
            **extra}


# The CLI in a child process, a chosen step of the store replaced by a stall: the child prints
# "stalled" and sleeps there until the test kills it.
_STALLED = """
import sys, time
import pipeline.store.folder as folder
import pipeline.store.postgres as postgres

def stall(*args, **kwargs):
    print("stalled", flush=True)
    time.sleep(600)

where = sys.argv[1]
if where == "commit":
    folder._FolderTransaction.commit = stall
    postgres._PostgresTransaction.commit = stall
elif where == "second part":
    write, calls = folder._FolderTransaction._write_part, []
    def second(self, *args):
        calls.append(1)
        if len(calls) == 2:
            stall()
        return write(self, *args)
    folder._FolderTransaction._write_part = second
from pipeline.cli import main
sys.exit(main(sys.argv[2:]))
"""


def start_stalled(where: str, argv: list[str]) -> subprocess.Popen:
    """``backlash ARGV`` in a child that stalls at ``where`` ("commit", "second part");
    returns once it stalled there."""
    child = subprocess.Popen([sys.executable, "-c", _STALLED, where, *argv], env=child_env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([child.stdout], [], [], 120)
    line = child.stdout.readline() if ready else ""
    if line.strip() != "stalled":
        child.kill()
        raise AssertionError(f"the child did not stall: {line!r} {child.stderr.read()[-2000:]}")
    return child


def run_cli(argv: list[str], **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *argv], env=child_env(**env),
                          capture_output=True, text=True, timeout=600, check=False)


def cli(capsys, argv) -> tuple[int, str, list[str]]:
    """Exit code, stdout and the non-empty stderr lines of ``backlash ARGV`` (in process)."""
    from pipeline.cli import main

    try:
        code = main([str(a) for a in argv])
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, [line for line in err.splitlines() if line.strip()]


def refused(capsys, argv) -> str:
    """``backlash ARGV`` ends with exit code 2 and exactly one stderr line, naming the command;
    returns it."""
    code, _, err = cli(capsys, argv)
    assert code == 2 and len(err) == 1, (code, err)
    assert err[0].startswith(f"backlash {argv[0]}: error: "), err
    return err[0]


def engine_location(request, tmp_path: Path, name: str) -> str:
    """A new store's location on the engine ``request.param`` names: a folder under
    ``tmp_path``, or a new database ``name_<random>`` on the test PostgreSQL server."""
    if request.param == "folder":
        return str(tmp_path / "fleet")
    import uuid

    from pg_server import create_database

    return create_database(request.getfixturevalue("postgres_url"),
                           f"{name}_{uuid.uuid4().hex[:10]}")
