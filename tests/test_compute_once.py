"""A job computes the per-target ISO statistics once and passes them down: ``fleet``,
``train``, ``drift`` and ``compensate`` each call ``features.iso230.per_target``'s work once
(the backlash points once where one definition serves every step)."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from features import iso230
from features import targets as ft
from features.readings.errors import BacklashWarning

DATA = Path(__file__).resolve().parents[1] / "experiments" / "data"
TWIN = DATA / "twin" / "readings.csv"
BUDGET = DATA / "paper_uncertainty.toml"
ESS = DATA / "ecmc" / "ess_mcu1025_ISO230.dat"


@pytest.fixture
def counts(monkeypatch):
    """Calls of the per-target statistics and of the backlash points during one job."""
    calls = {"stats": 0, "points": 0}

    def counted(name, function):
        def call(*args, **kwargs):
            calls[name] += 1
            return function(*args, **kwargs)
        return call

    monkeypatch.setattr(iso230, "_per_target", counted("stats", iso230._per_target))
    monkeypatch.setattr(ft, "targets_of", counted("points", ft.targets_of))
    return calls


def run(job: str):
    from pipeline.workflows.compensate import compensate
    from pipeline.workflows.drift import drift
    from pipeline.workflows.fleet import fleet
    from pipeline.workflows.train import train

    jobs = {"fleet": lambda: fleet(str(TWIN)),
            "drift": lambda: drift(str(TWIN), uncertainty=str(BUDGET)),
            "train": lambda: train(str(TWIN), model="ridge", uncertainty=str(BUDGET)),
            "compensate": lambda: compensate(str(ESS))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return jobs[job]()


@pytest.mark.parametrize("job", ["fleet", "drift", "train", "compensate"])
def test_a_job_computes_the_statistics_and_the_points_once(counts, job):
    run(job)
    assert counts == {"stats": 1, "points": 1}


def test_the_wear_clock_reuses_the_statistics(counts):
    """The default wear map also searches the visit series for adjustments: the same
    statistics and the same points (the table's, when its target is 'auto')."""
    from pipeline.workflows.train import train

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        train(str(TWIN))
    assert counts == {"stats": 1, "points": 1}


def test_the_counter_sees_a_second_computation(counts):
    """The counts above can fail: two independent calls are two."""
    from features.readings.io import read_readings
    from features.targets import backlash_targets

    readings = read_readings(str(ESS))
    backlash_targets(readings)
    iso230.axis_figures(readings)
    assert counts == {"stats": 2, "points": 1}


def test_compensate_writes_its_files_once_and_together(monkeypatch, tmp_path):
    """The files are made in memory, read back as each controller applies them, and reach
    the disk once, all together, through the folder writer a kill sweeps; no file is written
    on its own (the old path wrote every file twice, into a scratch folder first)."""
    from features.readings import fileio
    from pipeline.workflows.compensate import compensate

    calls = []
    write_files = fileio.write_files

    def counted(out, contents):
        calls.append(sorted(contents))
        return write_files(out, contents)

    def refused(path):
        raise AssertionError(f"{path} written on its own")

    monkeypatch.setattr(fileio, "write_files", counted)
    monkeypatch.setattr(fileio, "atomic_path", refused)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        result = compensate(str(ESS), controller="all")
    assert calls == []
    written = result.write(tmp_path / "c")
    assert len(calls) == 1 and calls[0] == sorted(written)
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == calls[0]
    assert all(written[name].read_bytes() == result.contents[name] for name in written)
    assert any(name.endswith(".COM") for name in written)  # Heidenhain, among the others
