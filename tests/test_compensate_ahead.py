"""`compensate MODEL_DIR --at-hours`: a wear map's table forecast ahead of wear.

Known truth: the twin's lost motion at every target during the next maintenance interval
(``truth.csv``). A table for the middle of the interval must leave a smaller backlash error,
averaged over the interval, than the table frozen at the visit.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import InputError
from pipeline.cli import main
from pipeline.workflows.compensate import compensate

QUARTERS = 4  # the twin is measured four times per maintenance interval
TRAINED = 4   # maintenance visits the model sees


def wear_config(machines: int = 2) -> dict:
    """The ``fleet`` preset's wear (uniform plus a worn zone at 120 mm), faster, on an indirect
    axis with a short linear plan; one visit every quarter of a 960 h interval."""
    return {"system": "indirect",
            "plan": {"start_mm": 0.0, "stop_mm": 300.0, "n_targets": 7, "feeds_mm_min": [500.0],
                     "dwells_s": [3.0], "repeats": 3, "cycles": 5, "methods": ["linear"]},
            "fleet": {"machines": machines, "axes": ["X"],
                      "visits": QUARTERS * TRAINED + 1, "interval_days": 60 / QUARTERS,
                      "hours_per_day": 16.0, "wear_um_per_1000h": 0.2,
                      "wear_local_um_per_1000h": 3.0, "wear_center_mm": 120.0}}


@pytest.fixture(scope="module")
def twin():
    """The twin's readings and truth, and a wear map trained on its maintenance visits (every
    fourth measurement) up to the last visit before the interval."""
    from models.physics.campaign import simulate
    from pipeline.workflows.train import train

    sim = simulate(wear_config(), seed=7)
    visits = sorted(sim.readings["visit"].astype(str).unique())
    trained = visits[:QUARTERS * (TRAINED - 1) + 1:QUARTERS]
    readings = sim.readings[sim.readings["visit"].astype(str).isin(trained)].copy()
    for column in readings.select_dtypes("category"):
        readings[column] = readings[column].cat.remove_unused_categories()
    model = train(readings, model="wear-map").trained
    return sim, visits, model


def interval_error(sim, visits, profile) -> float:
    """Mean over the next maintenance interval (its five measurements, trapezoid in time)
    and over the targets the table covers of |true lost motion - the table's backlash| [um]."""
    truth = sim.truth[(sim.truth["machine_id"].astype(str) == profile.machine_id)]
    during = visits[QUARTERS * (TRAINED - 1):]
    errors = []
    for visit in during:
        part = truth[truth["visit"].astype(str) == visit]
        true = part.groupby("target", observed=True)["true_backlash_um"].mean()
        true = true[(true.index >= profile.target.min()) & (true.index <= profile.target.max())]
        table = np.interp(true.index.to_numpy(float), profile.target, -profile.reversal)
        errors.append(float(np.mean(np.abs(true.to_numpy() - table))))
    weights = np.array([0.5, 1, 1, 1, 0.5])
    return float(np.sum(weights * errors) / np.sum(weights))


def test_mid_interval_table_beats_the_frozen_one(twin):
    sim, visits, model = twin
    hours = sim.visits.groupby("visit")["operating_hours"].first()
    last = float(hours[visits[QUARTERS * (TRAINED - 1)]])
    interval = float(hours[visits[-1]]) - last
    # the table at the measured targets (50 mm apart), where the wear map was fitted
    frozen = compensate(model, at_hours=last, spacing=50.0)
    middle = compensate(model, spacing=50.0)  # default: the middle of the next interval
    assert [p.at_hours for p in middle.profiles] == [pytest.approx(last + interval / 2)] * 2
    assert "middle of the next maintenance interval" in middle.profiles[0].notes[0]
    for f, m in zip(frozen.profiles, middle.profiles, strict=True):
        assert (f.machine_id, f.axis) == (m.machine_id, m.axis)
        before, ahead = interval_error(sim, visits, f), interval_error(sim, visits, m)
        # linear wear: the frozen table lags w I / 2 on average, the mid-interval one w I / 4
        assert ahead < 0.7 * before, (f.machine_id, before, ahead)


def test_machine_selection_and_hours_in_json(twin, tmp_path, capsys):
    _, _, model = twin
    from models.serving.registry import save_model

    save_model(model, tmp_path / "model")
    out = tmp_path / "out"
    assert main(["compensate", str(tmp_path / "model"), "--controller", "csv", "--out", str(out),
                 "--machine", "M02", "--at-hours", "2000", "--json"]) == 0
    axes = json.loads(capsys.readouterr().out)["axes"]
    assert [(a["machine_id"], a["axis"], a["at_hours"]) for a in axes] == [("M02", "X", 2000.0)]
    assert [p.name for p in out.iterdir()] == ["M02_X_compensation.csv"]


def test_training_records_each_axis_usage_rate_from_the_visits(twin):
    """The twin's hour counters run 16 h a day; the model records the last visit's date and
    reading, so a date 30 days later is 480 h on."""
    sim, visits, model = twin
    trained = sim.visits[sim.visits["visit"] == visits[QUARTERS * (TRAINED - 1)]]
    usage = {(u["machine_id"], u["axis"]): u for u in model.meta["usage"]}
    assert set(usage) == {("M01", "X"), ("M02", "X")}
    for _, visit in trained.iterrows():
        u = usage[(visit["machine_id"], visit["axis"])]
        assert u["hours_per_day"] == pytest.approx(16.0)
        assert u["last_hours"] == pytest.approx(visit["operating_hours"])
        assert u["last_date"] == visit["started_at"].date().isoformat()
    last = pd.Timestamp(usage[("M01", "X")]["last_date"])
    later = (last + pd.Timedelta(days=30)).date().isoformat()
    result = compensate(model, at_date=later, machine="M01")
    assert result.profiles[0].at_hours == pytest.approx(usage[("M01", "X")]["last_hours"] + 480)
    assert later in result.profiles[0].notes[0]


def test_a_model_without_usage_refuses_a_date(twin):
    _, _, model = twin
    usage = model.meta.pop("usage")
    try:
        with pytest.raises(InputError, match="does not record the axis's usage rate") as err:
            compensate(model, at_date="2027-07-01", machine="M01")
    finally:
        model.meta["usage"] = usage
    assert err.value.parameter == "at_date"


@pytest.mark.parametrize("options, message", [
    (["--at-hours", "-5"], "--at-hours: '-5': expected a float in the range [0.0, inf)"),
    (["--at-date", "2026-01-01"], "is before the axis's last visit"),
    (["--at-date", "July"], "'July' is not a date YYYY-MM-DD"),
    (["--at-hours", "10", "--at-date", "2026-07-01"], "not both"),
    (["--machine", "M09"], "selects no machine axis the model knows (M01 X, M02 X)"),
    (["--at-hours", "10", "--conditions", "operating_hours=5"], "give one of them"),
])
def test_bad_forecast_options(twin, tmp_path, capsys, options, message):
    _, _, model = twin
    from models.serving.registry import save_model

    save_model(model, tmp_path / "model")
    out = tmp_path / "out"
    assert main(["compensate", str(tmp_path / "model"), "--controller", "csv", "--out", str(out),
                 *options]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_at_hours_needs_a_wear_map_model(tmp_path, capsys, ess_file):
    import pandas as pd

    from models.serving.registry import TrainedModel, make, save_model

    X = pd.DataFrame({"target": [0.0, 100.0, 200.0]})
    model = TrainedModel("constant", make("constant").fit(X, np.full(3, 3.0)), ["target"],
                         "iso", 0.1, {"target": (0.0, 200.0)})
    save_model(model, tmp_path / "model")
    for source, message in ((tmp_path / "model", "needs a wear-map model"),
                            (ess_file, "applies to a wear-map model directory")):
        out = tmp_path / "out"
        assert main(["compensate", str(source), "--controller", "csv", "--out", str(out),
                     "--at-hours", "100"]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1
        assert not out.exists()
