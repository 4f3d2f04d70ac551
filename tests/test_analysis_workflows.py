"""The analysis jobs from Python (rank, replicate, drift, discover, hidden-effects): results on
real and twin data, files written by the result, parameters checked on entry with errors that
name the parameter (the CLI shows its option), notes as warnings, progress reported."""

from __future__ import annotations

import json
import tomllib
import warnings
from pathlib import Path

import pandas as pd
import pytest

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main
from pipeline.workflows import NAMES

REPO = Path(__file__).resolve().parents[1]
TWIN = REPO / "experiments" / "data" / "twin"


@pytest.fixture(scope="module")
def twin_rank():
    calls = []
    result = bl.rank(TWIN / "readings.csv", boot=10, dropcolumn=False,
                     progress=lambda *step: calls.append(step))
    return result, calls


def test_rank_from_python_gives_the_verdict_table(twin_rank, tmp_path):
    result, calls = twin_rank
    table = result.table
    assert {"verdict", "effect_um", "effect_low_um", "effect_high_um", "proxy_for",
            "anova_score"} <= set(table.columns)
    assert set(table["verdict"]) <= {"driver", "proxy", "undecided", "none"}
    assert result.drivers() == list(table.index[table["verdict"] == "driver"])
    assert "operating_hours" in result.drivers()  # the twin's screw wears over six visits
    assert calls[-1][0] == calls[-1][1]  # the progress callback hears the end
    assert any("no model given" in n for n in result.notes)
    files = result.write(tmp_path / "rank")
    assert files["html"].is_file() and files["effects"].stat().st_size > 1000
    assert json.loads(files["json"].read_text())["drivers"] == result.drivers()
    record = result.tracking_record()
    assert record.experiment == "rank" and record.artifact_path == "rank"
    assert sorted(record.artifacts) == sorted(files.values())
    assert record.metrics["n_drivers"] == len(result.drivers())


def test_rank_takes_a_read_frame_and_refuses_a_hand_made_one():
    frame = pd.DataFrame({"target": [0.0, 1.0], "deviation_um": [1.0, 2.0]})
    with pytest.raises(InputError, match="not a validated readings frame") as err:
        bl.rank(frame)
    assert err.value.parameter == "data"


@pytest.mark.parametrize("values, parameter, words", [
    ({"bins": 1}, "bins", "range [2, inf)"),
    ({"bins": "1"}, "bins", "at least 2 classes"),
    ({"bins": "two"}, "bins", "class count such as 4"),
    ({"k": 0}, "k", "range [1, inf)"),
    ({"rank_by": "votes"}, "rank_by", "'anova'"),
    ({"boot": -1}, "boot", "range [0, inf)"),
    ({"features": ["target", "target"]}, "features", "'target' twice"),
])
def test_rank_parameters_are_checked_on_entry(values, parameter, words):
    with pytest.raises(InputError) as err:
        bl.rank(TWIN / "no-such-file.csv", **values)  # refused before the file is read
    assert err.value.parameter == parameter and words in str(err.value)


def test_rank_cli_names_the_option_of_a_refused_parameter(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["rank", str(TWIN / "readings.csv"), "--out", str(out), "--bins", "1"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "backlash rank: error: --bins: must be at least 2 classes; got 1"
    assert not out.exists()


def test_drift_from_python_on_the_twin(tmp_path):
    result = bl.drift(TWIN / "readings.csv", threshold_um=4.0)
    (series,) = result.series
    assert (series.machine_id, series.axis) == ("M01", "X")
    assert len(series.visits) == 6 and series.trend["slope"] > 0
    assert [a["machine_id"] for a in result.alerts] == ["M01"] * len(series.alerts)
    assert result.to_dict()["series"][0]["threshold_um"] == 4.0
    files = result.write(tmp_path / "drift")
    assert {p.name for p in files.values()} == {"drift.png", "drift.html", "drift.json"}
    assert result.tracking_record().metrics["n_alerts"] == len(result.alerts)


def test_drift_of_a_read_frame_matches_the_file():
    frame = bl.read(TWIN / "readings.csv")
    a = bl.drift(frame).to_dict()
    b = bl.drift(TWIN / "readings.csv").to_dict()
    assert a == b


@pytest.mark.parametrize("values, parameter", [
    ({"threshold_um": -1.0}, "threshold_um"), ({"threshold_um": float("inf")}, "threshold_um"),
    ({"alpha": 0.7}, "alpha"), ({"alpha": float("nan")}, "alpha"),
    ({"warn_months": -1.0}, "warn_months"), ({"min_jump_sigma": 0.0}, "min_jump_sigma"),
    ({"format": "excel"}, "format"),
])
def test_drift_parameters_are_checked_on_entry(values, parameter):
    with pytest.raises(InputError) as err:
        bl.drift(TWIN / "readings.csv", **values)
    assert err.value.parameter == parameter


def test_drift_single_visit_axis_is_a_note(tmp_path):
    frame = bl.read(TWIN / "readings.csv")
    lone = frame[frame["visit"] == frame["visit"].iloc[0]].assign(axis="Y")
    with pytest.warns(BacklashWarning, match="M01 axis Y: a single visit"):
        result = bl.drift(pd.concat([frame, lone], ignore_index=True))
    assert result.notes == ["M01 axis Y: a single visit, no drift analysis"]
    assert len(result.series) == 1


def test_discover_from_python_on_a_real_test(ess_file, tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BacklashWarning)
        result = bl.discover(ess_file)
    assert result.named == ["lead_error_profile", "reversal_profile"]
    assert result.rmse_after_um <= 1.5 * result.repeatability_um
    shown = [str(w.message) for w in caught if w.category is BacklashWarning]
    # the reader's note (an ecmc file names no axis letter), then the workflow's own notes
    assert shown[0] == f"{ess_file}: the file states no axis; taken as X (name it with --axis)"
    assert shown[1:] == result.notes and any("direct measuring system" in n for n in shown)
    files = result.write(tmp_path / "new" / "discover")  # the folder is created
    assert files["html"].is_file() and files["png"].is_file()
    record = result.tracking_record()
    assert record.params["named"] == "lead_error_profile,reversal_profile"
    assert record.params["measuring_system"] == "direct"
    assert result.measuring_system["p_value"] > 0.05
    assert record.experiment == "discover"


@pytest.mark.parametrize("baseline, words", [
    ("backlash,gremlins", "unknown effect 'gremlins'"), (" , ", "empty"),
    (["backlash", "backlash"], "listed twice"),
])
def test_discover_baseline_errors_name_the_parameter(ess_file, baseline, words):
    with pytest.raises(InputError, match=words) as err:
        bl.discover(ess_file, baseline=baseline)
    assert err.value.parameter == "baseline" and "--" not in err.value.message


def test_replicate_parameters_are_checked_on_entry():
    with pytest.raises(InputError, match=r"range \[0, inf\)") as err:
        bl.replicate(TWIN / "readings.csv", boot=-1)
    assert err.value.parameter == "boot"


def small_benchmark() -> dict:
    """One null scenario on design A of the shipped scenario file."""
    spec = tomllib.loads((REPO / "experiments/hidden_effect_scenarios.toml").read_text())
    design = dict(spec["designs"]["A"], hidden=[], nulls=1)
    return {"baseline": spec["baseline"], "truth": spec["truth"], "designs": {"A": design}}


def test_hidden_effects_from_python_reports_progress(tmp_path):
    calls = []
    result = bl.hidden_effects(small_benchmark(), seeds=1, progress=lambda *s: calls.append(s))
    assert calls == [(0, 1, "null/A/1"), (1, 1, "done")]
    assert result.table["kind"].tolist() == ["null"] and result.score["null_scenarios"] == 1
    assert result.score["false_names_on_nulls"] == 0
    files = result.write(tmp_path / "bench")
    assert json.loads(files["score"].read_text())["scenarios"] == 1
    assert result.tracking_record().metrics["null_scenarios"] == 1


@pytest.mark.parametrize("values, parameter, words", [
    ({"seeds": 0}, "seeds", "range [1, inf)"),
    ({"scenarios": {"seeds": [1]}}, "scenarios", "no [designs.*]"),
    ({"scenarios": {"designz": {}}}, "scenarios", "unknown key 'designz'"),
])
def test_hidden_effects_parameters_are_checked(values, parameter, words):
    with pytest.raises(InputError) as err:
        bl.hidden_effects(**values)
    assert err.value.parameter == parameter and words in str(err.value)


@pytest.mark.parametrize("name", NAMES)
def test_every_parameter_has_a_constraint(name):
    """Every job's table covers its signature (``check_params`` skips no name)."""
    import inspect

    from pipeline.workflows import workflow

    record = workflow(name)
    module = inspect.getmodule(record.function)
    given = set(inspect.signature(record.function).parameters) - {"progress"}
    assert given <= set(module.PARAMETERS)
