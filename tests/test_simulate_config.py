"""Simulate configs follow the rules of the readings they produce: one line, exit 2, nothing
written, and a campaign too large for memory refused before any work."""

from __future__ import annotations

import time

import pytest

from pipeline.cli import main


@pytest.mark.parametrize("text, column, words", [
    ("[fleet]\naxes = ['X', 'Q']\n", "fleet.axes", "unknown axis 'Q'"),
    ("[fleet]\naxes = ['X', 'X']\n", "fleet.axes", "given twice"),
    ("[plan]\ntargets_mm = [0.0, nan, 100.0]\n", "plan.targets_mm", "finite"),
    ("[plan]\ntargets_mm = [0.0, 50.0, 50.0, 100.0]\n", "plan.targets_mm", "given twice"),
    ("[plan]\nfeeds_mm_min = [500.0, inf]\n", "plan.feeds_mm_min", "finite"),
    ("[plan]\nfeeds_mm_min = [500.0, 500.0]\n", "plan.feeds_mm_min", "given twice"),
    ("[plan]\ndwells_s = [5.0, 9000.0]\n", "plan.dwells_s", "dwell time"),
    ("[plan]\nfeeds_mm_min = ['fast']\n", "plan.feeds_mm_min", "list of numbers"),
    ("[plan]\nrepeats = 1.5\n", "plan.repeats", "whole number"),
    ("plan = 'paper'\n", "plan", "expected a table"),
    ("[fleet]\nmachines = [1, 2]\n", "fleet.machines", "expected a number"),
    ("[fleet.visits]\nn = 3\n", "fleet.visits", "expected a number"),
    ("[effects]\nbacklash = 2.0\n", "effects.backlash", "expected a table"),
    ("[effects.backlash]\nb0_um = 'big'\n", "effects.backlash.b0_um", "expected a number"),
    ("[effects.backlash]\nb0_um = nan\n", "effects.backlash.b0_um", "finite"),
    ("[environment]\nhumidity_pct = 140.0\n", "environment.humidity_pct", "relative humidity"),
    ("[fleet]\nstart = 'soon'\n", "fleet.start", "ISO 8601"),
    ("[fleet]\nwear_width_mm = 0.0\n", "fleet.wear_width_mm", "width"),
    ("system = ['direct']\n", "system", "expected text"),
])
def test_bad_simulate_config_one_line_nothing_written(tmp_path, capsys, text, column, words):
    path = tmp_path / "campaign.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["simulate", "--config", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert words in err[0] and f"column {column!r}" in err[0] and "campaign.toml" in err[0], err
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


def test_a_fleet_too_large_for_memory_is_refused_at_once(tmp_path, capsys):
    path = tmp_path / "huge.toml"
    path.write_text("[fleet]\nmachines = 100000\n")
    start = time.perf_counter()
    assert main(["simulate", "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    assert time.perf_counter() - start < 5.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "GB" in err[0] and "memory" in err[0], err
    assert not (tmp_path / "o").exists()


def test_estimate_counts_the_readings_the_twin_writes():
    from models.physics.campaign import load_config, n_readings, simulate

    config = load_config({"fleet": {"visits": 2, "axes": ["X", "Y"]}}, preset="demo")
    assert n_readings(config) == len(simulate(config, seed=0).readings)


def test_python_writes_the_traces_the_command_writes(tmp_path):
    """``simulate --traces`` and ``bl.simulate(traces=True)`` are one job: same seed, same
    files, the same truth (3 axes x 2 days)."""
    import pandas as pd

    import backlash as bl

    assert main(["simulate", "--traces", "--days", "2", "--seed", "3", "--out",
                 str(tmp_path / "cli")]) == 0
    result = bl.simulate(traces=True, days=2, seed=3, out=tmp_path / "py")
    assert result.files["truth"] == tmp_path / "py" / "traces_truth.csv"
    truth = pd.read_csv(result.files["truth"])
    assert len(truth) == 6 and sorted(truth["axis"].unique()) == ["X", "Y", "Z"]
    pd.testing.assert_frame_equal(truth, pd.read_csv(tmp_path / "cli" / "traces_truth.csv"))
    assert (tmp_path / "py" / "traces" / "machine_id=M01").is_dir()


@pytest.mark.parametrize("argv, option", [
    (["--days", "5"], "--days"), (["--rate-hz", "500"], "--rate-hz"),
    (["--traces", "--preset", "wear"], "--preset"), (["--traces", "--config", "c.toml"],
                                                     "--config")])
def test_options_of_the_other_kind_are_refused_not_ignored(tmp_path, capsys, argv, option):
    out = tmp_path / "out"
    assert main(["simulate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"backlash simulate: error: {option}: "), err
    assert not out.exists()


def test_python_refuses_a_campaign_parameter_with_traces():
    from features.readings.errors import InputError
    from pipeline.workflows.simulate import simulate

    with pytest.raises(InputError, match="not to controller traces") as err:
        simulate(traces=True, session_seed=2)
    assert err.value.parameter == "session_seed"
