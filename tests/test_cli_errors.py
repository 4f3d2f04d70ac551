"""The CLI's error contract for every command: a bad option or output path is one line with
exit code 2 and nothing left behind; a bug keeps its traceback; temporary files never
outlive a SIGTERM, and those of a SIGKILLed run are removed by the next run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import InputError
from features.readings.fileio import TEMP_MARK, atomic_path
from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]


def small_table(tmp_path) -> Path:
    rows = [{"machine_id": "M1", "axis": "X", "test_id": "T1", "method": "linear",
             "target": target, "direction": d, "cycle": c,
             "deviation_um": 0.01 * target + (2.0 if d == "-" else -2.0) + 0.1 * c}
            for c in (1, 2, 3) for d in "+-" for target in (0.0, 50.0, 100.0)]
    path = tmp_path / "readings.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def one_line(capsys, command: str) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    assert err[0].startswith(f"backlash {command}: error: "), err
    return err[0]


def refused(capsys, argv: list[str]) -> str:
    """main(argv) ends with exit code 2 (returned or raised by argparse) and one line."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    assert code == 2
    return one_line(capsys, argv[0])


def temps(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if TEMP_MARK in p.name] if folder.exists() else []


# --------------------------------------------------------------------- output paths


def test_out_pointing_at_a_folder_where_a_file_is_expected(tmp_path, capsys):
    (tmp_path / "out.csv").mkdir()
    line = refused(capsys, ["convert", str(small_table(tmp_path)), "--out",
                            str(tmp_path / "out.csv")])
    assert "--out is a folder; expected a file name" in line
    assert list((tmp_path / "out.csv").iterdir()) == []


def test_plot_pointing_at_a_folder(tmp_path, capsys):
    (tmp_path / "chart.png").mkdir()
    line = refused(capsys, ["iso", str(small_table(tmp_path)), "--plot",
                            str(tmp_path / "chart.png")])
    assert "--plot is a folder" in line


def test_out_under_a_file(tmp_path, capsys):
    (tmp_path / "taken").write_text("keep me")
    line = refused(capsys, ["convert", str(small_table(tmp_path)), "--out",
                            str(tmp_path / "taken" / "x.csv")])
    assert "taken is a file; expected a folder on the way" in line
    assert (tmp_path / "taken").read_text() == "keep me"


@pytest.mark.parametrize("command", ["simulate", "train", "rank", "drift", "discover"])
def test_out_pointing_at_a_file_where_a_folder_is_expected(tmp_path, capsys, command):
    target = tmp_path / "result"
    target.write_text("keep me")
    data = [] if command == "simulate" else [str(small_table(tmp_path))]
    line = refused(capsys, [command, *data, "--out", str(target)])
    assert "--out is a file; expected a folder" in line
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("out", ["/proc/backlash-test/x.csv", "/proc/x.csv"])
def test_unwritable_output_location(tmp_path, capsys, out):
    line = refused(capsys, ["convert", str(small_table(tmp_path)), "--out", out])
    assert out.rsplit("/", 1)[0] in line and "cannot" in line


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_folder_without_write_permission(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    line = refused(capsys, ["convert", str(small_table(tmp_path)), "--out",
                            str(locked / "x.csv")])
    assert "permission denied" in line


@pytest.mark.parametrize("argv", [
    ["convert", "{data}", "--out", ""],
    ["convert", "", "--out", "{tmp}/x.csv"],
    ["discover", "{data}", "--out", "{tmp}/d", "--baseline", " "],
])
def test_empty_text_option_or_argument(tmp_path, capsys, argv):
    data = small_table(tmp_path)
    line = refused(capsys, [a.format(data=data, tmp=tmp_path / "o") for a in argv])
    assert "expected a value, got an empty string" in line
    assert not (tmp_path / "o").exists()


def test_output_file_follows_the_umask(tmp_path):
    out = tmp_path / "x.csv"
    with atomic_path(out) as tmp:
        tmp.write_text("a\n")
    mask = os.umask(0)
    os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask


# --------------------------------------------------------------------- option values


@pytest.mark.parametrize("argv, words", [
    (["drift", "{data}", "--out", "{tmp}/d", "--threshold-um", "inf"], "expected a finite"),
    (["drift", "{data}", "--out", "{tmp}/d", "--alpha", "nan"], "expected a finite"),
    (["drift", "{data}", "--out", "{tmp}/d", "--warn-months", "six"], "'six' is not a number"),
    (["rank", "{data}", "--out", "{tmp}/r", "--k", "0"],
     "--k: '0': expected an int in the range [1, inf)"),
    (["tune", "{data}", "--trials", "2.5"], "'2.5' is not a whole number"),
    (["tune", "{data}", "--seed", "-1"],
     "--seed: '-1': expected an int in the range [0, 4294967295]"),
    (["simulate", "--out", "{tmp}/s", "--seed", str(2**32)],
     "--seed: '4294967296': expected an int in the range [0, 4294967295]"),
    (["convert", "{data}", "--out", "{tmp}/c.csv", "--format", "excel"], "invalid choice"),
    (["convert", "{data}", "--out", "{tmp}/c.csv", "--colour", "red"], "unrecognized"),
    (["convert", "{data}"], "required: --out"),
])
def test_bad_option_value_is_one_line_and_writes_nothing(tmp_path, capsys, argv, words):
    data = small_table(tmp_path)
    argv = [a.format(data=data, tmp=tmp_path / "o") for a in argv]
    line = refused(capsys, argv)
    assert words in line
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------- error paths


def test_value_error_from_a_command_is_one_line(tmp_path, capsys, monkeypatch):
    def run(args):
        raise ValueError("alpha must lie in (0, 1),\n got 2")

    monkeypatch.setattr("pipeline.commands.convert.run", run)
    line = refused(capsys, ["convert", str(small_table(tmp_path)), "--out",
                            str(tmp_path / "x.csv")])
    assert line.endswith("alpha must lie in (0, 1), got 2")


def test_unexpected_exception_keeps_its_traceback(tmp_path, monkeypatch):
    def run(args):
        raise KeyError("a bug")

    monkeypatch.setattr("pipeline.commands.convert.run", run)
    with pytest.raises(KeyError, match="a bug"):
        main(["convert", str(small_table(tmp_path)), "--out", str(tmp_path / "x.csv")])


def test_output_folder_created_by_a_failed_run_is_removed(tmp_path, capsys, monkeypatch):
    def run(args):
        Path(args.out, "part").mkdir(parents=True)
        Path(args.out, "part", "half.csv").write_text("half")
        raise InputError("bad data", file="x.csv", row=3)

    monkeypatch.setattr("pipeline.commands.simulate.run", run)
    line = refused(capsys, ["simulate", "--out", str(tmp_path / "new" / "sim")])
    assert line.endswith("x.csv, row 3: bad data")
    assert not (tmp_path / "new").exists()
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "mine.txt").write_text("keep")
    refused(capsys, ["simulate", "--out", str(tmp_path / "old")])
    assert (tmp_path / "old" / "mine.txt").read_text() == "keep"


# --------------------------------------------------------------------- signals


def _big_readings(path: Path, tests: int) -> Path:
    grid = pd.MultiIndex.from_product(
        [[f"T{i}" for i in range(tests)], [1, 2, 3], ["+", "-"], np.arange(0.0, 100.0, 10.0)],
        names=["test_id", "cycle", "direction", "target"]).to_frame(index=False)
    grid = grid.assign(machine_id="M1", axis="X", method="linear")
    grid["deviation_um"] = (np.where(grid["direction"] == "+", -2.0, 2.0)
                            + 0.01 * grid["target"] + 0.1 * grid["cycle"])
    grid.to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory):
    """About 150 000 readings: converting them takes long enough to be interrupted."""
    return _big_readings(tmp_path_factory.mktemp("big") / "big.csv", tests=2500)


def _cli(*argv) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "pipeline.cli", *argv], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _signal_while_writing(proc, folder: Path, sig) -> list[Path]:
    """Send ``sig`` as soon as a temporary file appears in ``folder``; return what was seen."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        seen = temps(folder)
        if seen:
            proc.send_signal(sig)
            proc.wait(timeout=60)
            return seen
        time.sleep(0.002)
    pytest.fail(f"no temporary file appeared; exit {proc.wait()}: {proc.stderr.read()}")


def test_sigterm_during_convert_removes_the_temporary_file(tmp_path, big_csv):
    out = tmp_path / "out"
    proc = _cli("convert", str(big_csv), "--out", str(out / "big.csv"))
    seen = _signal_while_writing(proc, out, signal.SIGTERM)
    err = proc.stderr.read()
    assert seen and proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert list(out.iterdir()) == []


# SIGTERM right as the temporary file is created (the race the convert test above hit now
# and then): sent to the process, or taken by a second thread (pandas, pyarrow and tqdm start
# them). The kernel hands a process's SIGTERM to any thread that does not block it, and Python
# runs the handler in the main thread at its next instruction, wherever that is: masking the
# signal in the main thread did not hold it back, and a file made before it was registered
# stayed behind.
SIGTERM_AT_CREATION = """
import os, signal, sys, tempfile, threading, time
from features.readings import fileio
other = threading.Thread(target=time.sleep, args=(30,), daemon=True)
other.start()
def signalled(make):
    def call(*args, **kwargs):
        out = make(*args, **kwargs)
        if sys.argv[2] == "thread":
            signal.pthread_kill(other.ident, signal.SIGTERM)
            time.sleep(0.05)  # the other thread takes it; the handler is now pending
        else:
            os.kill(os.getpid(), signal.SIGTERM)
        return out
    return call
tempfile.mkstemp = signalled(tempfile.mkstemp)
os.open = signalled(os.open)
with fileio.atomic_path(sys.argv[1]) as tmp:
    tmp.write_text("half")
"""


@pytest.mark.parametrize("taken_by", ["process", "thread"])
def test_sigterm_as_the_temporary_file_is_created_leaves_nothing(tmp_path, taken_by):
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.run([sys.executable, "-c", SIGTERM_AT_CREATION, str(out / "x.csv"),
                           taken_by], env={**os.environ, "PYTHONPATH": str(REPO)},
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert "Traceback" not in proc.stderr
    assert list(out.iterdir()) == []


def test_temporary_file_of_a_sigkilled_convert_is_removed_by_the_next_run(tmp_path, big_csv):
    out = tmp_path / "out"
    proc = _cli("convert", str(big_csv), "--out", str(out / "big.csv"))
    _signal_while_writing(proc, out, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    orphans = temps(out)
    assert orphans, "SIGKILL cannot be caught: the temporary file must still be there"
    small = _big_readings(tmp_path / "small.csv", tests=2)
    again = _cli("convert", str(small), "--out", str(out / "small.csv"))
    assert again.wait(timeout=120) == 0, again.stderr.read()
    assert sorted(p.name for p in out.iterdir()) == ["small.csv"]


def test_sigterm_during_simulate_leaves_no_temporary_folder(tmp_path):
    out = tmp_path / "sim"
    script = ("import sys, time\n"
              "from pipeline.commands import simulate\n"
              "from features.readings import fileio\n"
              "def slow(*a, **k):\n"
              "    print('writing', flush=True); time.sleep(60)\n"
              "fileio.write_json = slow\n"
              "from pipeline.cli import main\n"
              f"sys.exit(main(['simulate', '--preset', 'demo', '--out', {str(out)!r}]))\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
    assert temps(tmp_path), "simulate writes into a temporary folder first"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    assert list(tmp_path.iterdir()) == []


def test_orphans_of_live_or_recent_writers_are_kept(tmp_path):
    from features.readings.fileio import sweep_orphans

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          check=True, capture_output=True, text=True).stdout.strip()
    old = time.time() - 3600
    files = {
        "dead_old": tmp_path / f".x.csv.abc{TEMP_MARK}{dead}.csv",
        "alive_old": tmp_path / f".y.csv.abc{TEMP_MARK}{os.getppid()}.csv",
        "dead_new": tmp_path / f".z.csv.abc{TEMP_MARK}{dead}.csv",
        "not_ours": tmp_path / f".w.csv.abc.tmp{dead}.csv",
    }
    for name, path in files.items():
        path.write_text(name)
        if name != "dead_new":
            os.utime(path, (old, old))
    os.utime(files["dead_new"], (time.time() + 3600,) * 2)  # written after this process began
    removed = sweep_orphans(tmp_path)
    assert removed == [files["dead_old"]]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        files[k].name for k in ("alive_old", "dead_new", "not_ours"))


def test_convert_refuses_to_overwrite_its_input(tmp_path, capsys):
    data = small_table(tmp_path)
    before = data.read_bytes()
    line = refused(capsys, ["convert", str(data), "--out", str(tmp_path / "." / data.name)])
    assert "--out is the input file" in line
    assert data.read_bytes() == before
