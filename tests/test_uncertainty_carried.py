"""The measurement uncertainty U(B) (ISO/TR 230-9 budget) carried into drift and training.

Known truth: the backlash paper's budget (experiments/data/paper_uncertainty.toml) gives
U(B) = 4.12 um (Table 4) from u_S = √2·50 mm·50 um/m/(2√3) and u_EVE = 1 um/(2√3) with n = 5;
hand-made series with a known step; the twin's drift fleet with its true events.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_drift import _run, visit_readings

from features.readings.errors import InputError
from models.estimators import evaluation

BUDGET = "experiments/data/paper_uncertainty.toml"
K = 2.0
U_S = math.sqrt(2.0) * 50.0 * 50.0e-3 / (2 * math.sqrt(3))  # Abbe setup term [um]
U_EVE = 1.0 / (2 * math.sqrt(3))                              # environmental variation [um]
U_B = K * math.sqrt((2 * U_S) ** 2 + (2 * U_EVE) ** 2 / 5)    # the paper's 4.12 um


def step_series(step_um, n_before=8, n_after=6):
    """A flat series at 2 um stepping by ``step_um`` at visit 9 (one linear test per visit,
    reading noise 0.05 um: the step is many standard errors of the repeatability)."""
    return visit_readings(np.r_[np.full(n_before, 2.0), np.full(n_after, 2.0 + step_um)],
                          noise_um=0.05)


def test_paper_budget_gives_the_papers_U_B():
    assert U_B == pytest.approx(4.12, abs=0.005)


def test_each_visit_carries_U_of_its_backlash(tmp_path, capsys):
    _, out = _run(tmp_path, step_series(3.0), "--uncertainty", BUDGET, capsys=capsys)
    s = out["series"][0]
    u_r = np.array(s["backlash_u_um"])
    # U = k √((U(B)/k)² + u_r²): the budget's U(B) with the repeatability of the visit
    np.testing.assert_allclose(s["backlash_U_um"], K * np.hypot(U_B / K, u_r), atol=2e-4)
    assert s["coverage_factor"] == K


def test_step_below_U_is_within_the_uncertainty_not_an_alert(tmp_path, capsys):
    frame = step_series(0.5)
    # without a budget the 0.5 um step is a failure alert (many sigma of the repeatability)
    code, out = _run(tmp_path, frame, capsys=capsys)
    assert code == 3 and out["series"][0]["change_points"] == ["v09"]
    code, out = _run(tmp_path, frame, "--uncertainty", BUDGET, capsys=capsys)
    s = out["series"][0]
    assert code == 0 and s["alerts"] == [] and s["change_points"] == []
    (step, *rest) = s["within_uncertainty"]
    assert step["visit"] == "v09" and step["kind"] == "change_point"
    assert step["jump_um"] == pytest.approx(0.5, abs=0.1)
    # U(Δ) = k √(u_v,8² + u_v,9²), u_v² = (2u_EVE)²/n + u_r²: the setup's Abbe part cancels
    u_r = np.array(s["backlash_u_um"])
    u_v = np.sqrt((2 * U_EVE) ** 2 / 5 + u_r ** 2)
    assert step["U_um"] == pytest.approx(K * np.hypot(u_v[7], u_v[8]), abs=2e-4)
    assert 0.5 < step["U_um"] < U_B  # smaller than the U of one visit's value
    assert all(w["kind"] == "trend" for w in rest)
    report = json.loads((tmp_path / "out" / "drift.json").read_text())
    assert report["series"][0]["within_uncertainty"][0]["visit"] == "v09"
    assert "within the measurement uncertainty" in (tmp_path / "out" / "drift.html").read_text(
        encoding="utf-8")


def test_step_above_U_is_still_a_failure(tmp_path, capsys):
    code, out = _run(tmp_path, step_series(3.0), "--uncertainty", BUDGET, capsys=capsys)
    s = out["series"][0]
    assert code == 3 and s["change_points"] == ["v09"] and s["within_uncertainty"] == []
    assert "level_jump" in [a["kind"] for a in s["alerts"]]
    assert s["change_U_um"][0] < s["change_jumps_um"][0]
    html = (tmp_path / "out" / "drift.html").read_text(encoding="utf-8")
    assert "U [µm]" in html and "k = 2" in html


def test_without_budget_the_json_is_unchanged(tmp_path, capsys):
    _, out = _run(tmp_path, step_series(3.0), capsys=capsys)
    s = out["series"][0]
    assert not {"backlash_U_um", "change_U_um", "within_uncertainty", "coverage_factor"} & set(s)


def test_printed_table_shows_U(tmp_path, capsys):
    from pipeline import cli

    path = tmp_path / "r.csv"
    step_series(0.5).to_csv(path, index=False)
    assert cli.main(["drift", str(path), "--out", str(tmp_path / "o"),
                     "--uncertainty", BUDGET]) == 0
    err = capsys.readouterr().err
    header, row = err.splitlines()[:2]
    assert " U " in header and "unit" in header and "  4.12 " in row  # U(B), u_r ~0.03 um
    assert "within the measurement uncertainty: the step of +0.5" in err


def test_twin_fleet_changes_are_still_found_with_the_budget():
    from models.physics.campaign import simulate
    from pipeline.workflows.drift import drift

    sim = simulate("drift", seed=1)
    # the campaign runs into 2027: the view is as of its last visit, not today
    last = sim.readings["started_at"].max().date().isoformat()
    result = drift(sim.readings, uncertainty=BUDGET, as_of=last)
    assert len(result.series) == 3
    for s in result.series:
        events = sim.visits[(sim.visits["machine_id"] == s.machine_id)
                            & (sim.visits["event"] != "")]["visit"].tolist()
        j = s.to_dict()
        assert j["change_points"] == events  # the adjustment and the failure exceed U(Δ)
        assert all(u < abs(d) for u, d in zip(j["change_U_um"], j["change_jumps_um"]))
        assert min(j["backlash_U_um"]) >= U_B - 0.01
        # the twin has no event at its last visit: M03's last visit lies +0.54 um off its
        # trend, 3.4 sigma of the repeatability but within 3 standard errors once the trend
        # line's own error at the last visit counts (models.condition.drift._last_visit_jump); either
        # way it is within U(Δ) and no alert
        assert not {"last_visit_jump", "last_visit_drop"} & {a["kind"] for a in j["alerts"]}
        assert j["change_points"][-1] != "20"


# --------------------------------------------------------------------------- training
@pytest.fixture(scope="module")
def trained():
    from pipeline.workflows.train import train

    return train("experiments/data/twin/readings.csv", uncertainty=BUDGET)


def test_train_scores_the_error_against_U_B(trained):
    m, fit = trained.metrics, trained.fit
    assert m["U_B_um"] == pytest.approx(U_B, abs=1e-3)
    error = np.abs(fit.predicted_um - fit.table.y.to_numpy(float))[fit.test_index]
    assert m["test_abs_error_p95_um"] == pytest.approx(np.percentile(error, 95))
    assert m["test_rmse_over_U_B"] == pytest.approx(m["test_rmse_um"] / U_B)
    assert trained.to_dict()["resolution"] == "within what the measurement can resolve"
    assert trained.trained.meta["uncertainty"]["verdict"] == trained.to_dict()["resolution"]


def test_verdict_beyond_when_the_error_exceeds_U():
    m = evaluation.against_uncertainty([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 9.0], 4.12)
    # |error| 0, 0, 0, 5: the 95th percentile lies 0.85 of the way from 0 to 5 (linear)
    assert m["test_abs_error_p95_um"] == pytest.approx(4.25)
    assert evaluation.resolution_verdict(m) == "beyond what the measurement can resolve"


def test_train_model_json_and_summary(tmp_path, trained, capsys):
    from pipeline.commands.train import print_metrics

    trained.write(tmp_path / "model")
    meta = json.loads((tmp_path / "model" / "model.json").read_text())
    assert meta["uncertainty"]["U_B_um"] == pytest.approx(U_B, abs=1e-3)
    import sys

    print_metrics(trained.model, trained.metrics, file=sys.stderr)
    assert "against U(B) 4.115 um (k = 2): within what the measurement" in \
        capsys.readouterr().err


# --------------------------------------------------------------------------- bad input
def _rotary(tmp_path):
    path = tmp_path / "rotary.csv"
    visit_readings([2.0, 2.5, 3.0], axis="C").to_csv(path, index=False)
    return path


@pytest.mark.parametrize("command", ["drift", "train"])
@pytest.mark.parametrize("case", ["missing", "invalid", "rotary"])
def test_bad_budget_is_one_line_exit_2_nothing_written(tmp_path, capsys, command, case):
    from pipeline import cli

    data = tmp_path / "r.csv"
    step_series(3.0).to_csv(data, index=False)
    budget = BUDGET
    if case == "missing":
        budget = str(tmp_path / "nope.toml")
    elif case == "invalid":
        budget = tmp_path / "bad.toml"
        budget.write_text(Path(BUDGET).read_text().replace("cycles = 5", "cycles = 1"))
    else:
        data = _rotary(tmp_path)
    out = tmp_path / "o"
    argv = [command, str(data), "--out", str(out), "--uncertainty", str(budget)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert {"missing": "nope.toml", "invalid": "cycles", "rotary": "rotary"}[case] in err
    assert not out.exists()


def test_budget_for_rotary_axis_in_python(tmp_path):
    from pipeline.workflows.drift import drift

    with pytest.raises(InputError, match="holds lengths, not angles"):
        drift(str(_rotary(tmp_path)), uncertainty=BUDGET)
