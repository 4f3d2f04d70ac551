"""One definition of an axis's backlash at a visit (docs/backlash.md), checked against truth.

Two sources of truth: the twin (a direct measuring system, linear and pendulum tests, wear and
an adjustment) and a small generator of this file's own, which mixes a machine with a linear
scale (direct) and a machine with a rotary encoder (indirect) in one readings file.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features.readings import read_readings
from features.readings.errors import BacklashWarning
from features.table import feature_table
from features.targets import backlash_targets
from features.visits import DAYS_PER_MONTH, axis_backlash, months_between, visit_backlash
from models.condition import drift
from models.estimators.evaluation import target_noise_floor, true_backlash

# --------------------------------------------------------------------------- own generator
TARGETS_MM = np.array([4.0, 51.0, 97.0, 152.0, 203.0, 249.0])  # irregular, 4 interior
CYCLES = 5
NOISE_UM = 0.15
LINEAR_COOLER_UM = 0.4      # the linear run's screw is cooler: its lost motion is smaller
START = pd.Timestamp("2025-03-03T07:30:00Z")


def lost_motion_um(method: str, direct: bool, target, up, b_um: float) -> np.ndarray:
    """Deviation [um] that a play of width ``b_um`` adds to each reading.

    Indirect system (rotary encoder): every reading carries -sign*b/2. Direct system (linear
    scale): only readings right after a reversal do; in a linear cycle that is the first target
    of the up stroke and the last target of the travel, where the down stroke starts; in a
    pendulum cycle every reading.
    """
    sign = np.where(up, 1.0, -1.0)
    shows = np.ones(len(up), bool)
    if direct and method == "linear":
        shows = (up & (target == TARGETS_MM[0])) | (~up & (target == TARGETS_MM[-1]))
    return -sign * b_um / 2 * shows


def axis_readings(machine: str, axis: str, direct: bool, b_um, *, seed: int,
                  methods=("linear", "pendulum")) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Monthly visits of one axis: readings and truth (``true_backlash_um`` per reading).

    ``b_um[v]`` is the pendulum run's lost motion at visit v; the linear run's is
    ``LINEAR_COOLER_UM`` smaller. The pendulum run is warmer: a common-mode expansion
    proportional to position, and a machine temperature 1 K above the linear run's.
    """
    rng = np.random.default_rng(seed)
    target, cycle, up = (a.ravel() for a in np.meshgrid(TARGETS_MM, np.arange(1, CYCLES + 1),
                                                          [True, False], indexing="ij"))
    parts, truth = [], []
    for v, b in enumerate(np.asarray(b_um, float)):
        for method in methods:
            pendulum = method == "pendulum"
            b_run = b if pendulum else b - LINEAR_COOLER_UM
            deviation = (0.004 * target + 0.3 * np.sin(target / 40.0)      # lead error
                         + (0.8 * target / 250.0 if pendulum else 0.0)       # warmer screw
                         + lost_motion_um(method, direct, target, up, b_run)
                         + rng.normal(0.0, NOISE_UM, target.size))
            frame = pd.DataFrame({
                "machine_id": machine, "axis": axis, "visit": f"v{v + 1:02d}",
                "test_id": f"{machine}-{axis}-{v + 1:02d}-{method}", "method": method,
                "target": target, "direction": np.where(up, "+", "-"), "cycle": cycle,
                "deviation_um": deviation, "feed_mm_min": 800.0, "dwell_s": 4.0, "repeat": 1,
                "machine_temp_c": 21.0 if pendulum else 20.0,
                "started_at": (START + pd.Timedelta(days=v * DAYS_PER_MONTH,
                                                    hours=2 if pendulum else 0))
                .strftime("%Y-%m-%dT%H:%M:%SZ")})
            parts.append(frame)
            truth.append(frame[["machine_id", "axis", "visit", "test_id", "method", "feed_mm_min",
                                "dwell_s", "repeat", "target", "direction"]]
                         .assign(true_backlash_um=b_run))
    return pd.concat(parts, ignore_index=True), pd.concat(truth, ignore_index=True)


DIRECT_B = 2.0 + 0.3 * np.arange(6)      # pendulum run's lost motion per visit [um]
INDIRECT_B = 4.0 + 0.15 * np.arange(6)


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """A fleet file: machine D1 (axis X) with a linear scale, I1 (axis Y) with an encoder."""
    direct, truth_d = axis_readings("D1", "X", True, DIRECT_B, seed=11)
    indirect, truth_i = axis_readings("I1", "Y", False, INDIRECT_B, seed=12)
    path = tmp_path_factory.mktemp("mixed") / "readings.csv"
    pd.concat([direct, indirect], ignore_index=True).to_csv(path, index=False)
    return read_readings(path), pd.concat([truth_d, truth_i], ignore_index=True)


def true_level(truth: pd.DataFrame, machine: str, method: str | None) -> np.ndarray:
    """Truth per visit: mean over the tests that show the lost motion (None: all tests)."""
    mine = truth[truth["machine_id"] == machine]
    if method:
        mine = mine[mine["method"] == method]
    return mine.groupby("visit")["true_backlash_um"].mean().to_numpy()


# --------------------------------------------------------------------------- per machine axis
def test_each_axis_of_a_mixed_file_gets_its_own_target_kind(mixed):
    readings, _ = mixed
    points = backlash_targets(readings)
    kinds = points.groupby(["machine_id", "axis"])["target_kind"].unique()
    assert kinds.map(list).to_dict() == {("D1", "X"): ["paper"], ("I1", "Y"): ["iso"]}
    assert points.attrs["target_kind"] == "mixed"
    reason = points.attrs["target_reason"]
    assert "paper on D1 X" in reason and "iso on I1 Y" in reason, reason
    # explicit kinds still apply to every axis: the paper target on the encoder machine sees
    # only the difference of the two runs' lost motion, not the 4-5 um of play
    paper = backlash_targets(readings, "paper")
    assert paper.attrs["target_kind"] == "paper" and (paper["target_kind"] == "paper").all()
    assert paper.loc[paper["machine_id"] == "I1", "backlash_um"].mean() == pytest.approx(
        LINEAR_COOLER_UM, abs=0.1)


def test_point_levels_of_both_systems_agree_with_the_truth(mixed):
    readings, truth = mixed
    points = backlash_targets(readings)
    for machine, method in (("D1", "pendulum"), ("I1", None)):
        mine = points[points["machine_id"] == machine]
        assert set(mine["target"]) <= set(TARGETS_MM)
        got = mine.groupby("visit")["backlash_um"].mean().to_numpy()
        np.testing.assert_allclose(got, true_level(truth, machine, method), atol=0.2)
    # paper points only at interior targets; iso points at every target
    assert set(points.loc[points["machine_id"] == "D1", "target"]) == set(TARGETS_MM[1:-1])
    assert set(points.loc[points["machine_id"] == "I1", "target"]) == set(TARGETS_MM)


def test_visit_series_is_the_lost_motion_within_its_uncertainty(mixed):
    readings, truth = mixed
    table = visit_backlash(readings)
    assert table.attrs["target_kind"] == "mixed"
    for machine, kind, method in (("D1", "paper", "pendulum"), ("I1", "iso", None)):
        mine = table[table["machine_id"] == machine]
        assert (mine["target_kind"] == kind).all() and (mine["n_points"] == 4).all()
        error = mine["backlash_um"].to_numpy() - true_level(truth, machine, method)
        assert (np.abs(error) < 3 * mine["backlash_u_um"].to_numpy()).all(), (machine, error)
        # u of the mean of 4 points: paper 2 s/sqrt(5)/2, iso (two tests) half of that
        u = NOISE_UM / np.sqrt(5) * (1.0 if kind == "paper" else 0.5)
        np.testing.assert_allclose(mine["backlash_u_um"], u, rtol=0.35)
    # the mean signed ISO reversal value reads a direct system's lost motion about half
    direct = table[table["machine_id"] == "D1"]
    share = direct["reversal_mean_um"].abs().to_numpy() / DIRECT_B
    assert ((share > 0.4) & (share < 0.7)).all(), share
    indirect = table[table["machine_id"] == "I1"]
    np.testing.assert_allclose(-indirect["reversal_mean_um"], true_level(truth, "I1", None),
                               atol=0.1)


def test_axis_backlash_is_what_visit_backlash_reports(mixed):
    readings, _ = mixed
    table = visit_backlash(readings)
    plain = axis_backlash(readings)
    merged = table.merge(plain, on=["machine_id", "axis", "visit"], suffixes=("", "_plain"))
    assert len(merged) == len(table) == 12
    np.testing.assert_array_equal(merged["backlash_um"], merged["backlash_um_plain"])
    np.testing.assert_array_equal(merged["target_kind"], merged["target_kind_plain"])


def test_a_visit_with_one_test_method_falls_back_to_the_reversal_value(mixed):
    readings, truth = mixed
    only_pendulum = (readings["machine_id"] == "D1") & (readings["visit"] == "v03") & (
        readings["method"] == "linear")
    points = backlash_targets(readings[~only_pendulum])
    d1 = points[points["machine_id"] == "D1"]
    assert set(d1.loc[d1["visit"] == "v03", "target_kind"]) == {"iso"}
    assert set(d1.loc[d1["visit"] != "v03", "target_kind"]) == {"paper"}
    assert "one test method only (D1 X visit v03)" in points.attrs["target_reason"]
    # a pendulum test alone shows the lost motion at every target: |B_i| is still b
    level = d1.loc[d1["visit"] == "v03", "backlash_um"].mean()
    assert level == pytest.approx(true_level(truth, "D1", "pendulum")[2], abs=0.15)
    only_linear = (readings["machine_id"] == "D1") & (readings["visit"] == "v04") & (
        readings["method"] == "pendulum")
    with pytest.warns(BacklashWarning, match="D1 X visit v04: only linear tests on a direct"):
        backlash_targets(readings[~only_linear])


# --------------------------------------------------------------------------- downstream
def test_mixed_feature_table_takes_each_points_kind(mixed):
    readings, truth = mixed
    with pytest.warns(BacklashWarning, match="ISO target on some machine axes"):
        table = feature_table(readings)
    assert table.target_kind == "mixed" and "deviation_up_um" not in table.X
    kind = table.meta["target_kind"]
    # conditions from the tests that show the backlash: the pendulum run (21 degC) for paper
    # points, both runs for iso points
    np.testing.assert_allclose(table.X.loc[kind == "paper", "machine_temp_c"], 21.0)
    np.testing.assert_allclose(table.X.loc[kind == "iso", "machine_temp_c"], 20.5)
    # truth per point: the pendulum run for paper points, both runs for iso points
    expected = np.where(kind == "paper", table.meta["visit"].map(
        dict(zip([f"v{i + 1:02d}" for i in range(6)], DIRECT_B, strict=True))),
        table.meta["visit"].map(dict(zip([f"v{i + 1:02d}" for i in range(6)],
                                         INDIRECT_B - LINEAR_COOLER_UM / 2, strict=True))))
    np.testing.assert_allclose(true_backlash(table.meta, truth, table.target_kind), expected)
    assert np.sqrt(np.mean((table.y - expected) ** 2)) < 0.15
    # a model trained on a mixed table records 'mixed': asking for it again re-decides per axis
    again = feature_table(readings, target="mixed", features=list(table.X.columns))
    assert again.target_kind == "mixed" and again.meta["target_kind"].equals(kind)


def test_noise_floor_of_a_mixed_table_lies_between_the_two_kinds(mixed):
    readings, _ = mixed
    paper, iso = (target_noise_floor(readings, k) for k in ("paper", "iso"))
    assert paper == pytest.approx(np.sqrt(2) * iso)
    kinds = backlash_targets(readings)["target_kind"]
    share = float(np.mean(kinds == "paper"))
    mixed_floor = target_noise_floor(readings, "mixed")
    assert mixed_floor == pytest.approx(iso * np.sqrt(2 * share + (1 - share)))
    assert iso < mixed_floor < paper
    assert target_noise_floor(readings, kinds) == pytest.approx(mixed_floor)


def test_drift_of_a_mixed_file_names_its_quantity(mixed, tmp_path):
    from pipeline.workflows.drift import drift as drift_workflow

    readings, truth = mixed
    result = drift_workflow(readings)
    series = {s.machine_id: s.to_dict() for s in result.series}
    assert series["D1"]["target_kind"] == ["paper"] * 6
    assert series["I1"]["target_kind"] == ["iso"] * 6
    for key in ("backlash_um", "backlash_u_um", "n_points", "reversal_mean_um",
                "reversal_max_um"):
        assert len(series["D1"][key]) == 6, key
    assert not {"u_um", "B_um", "B_mean_um"} & set(series["D1"])
    np.testing.assert_allclose(series["D1"]["backlash_um"], true_level(truth, "D1", "pendulum"),
                               atol=0.2)
    # the slope follows the lost motion, 0.3 um a month, not a diluted reversal value
    low, high = series["D1"]["slope_interval"]
    assert low <= 0.3 <= high and series["D1"]["slope_um_per_month"] == pytest.approx(0.3,
                                                                                    abs=0.06)
    page = result.write(tmp_path / "drift")["html"].read_text(encoding="utf-8")
    assert "pendulum − linear" in page and "ISO |B_i|" in page
    assert "u(backlash)" in page and "|B_mean|" not in page


# --------------------------------------------------------------------------- the twin
@pytest.fixture(scope="module")
def direct_twin():
    """Direct measuring system, linear and pendulum tests at two feeds, wear, an adjustment
    at visit 6 of 10."""
    from models.physics.campaign import simulate

    return simulate({"system": "direct",
                     "plan": {"feeds_mm_min": [500.0, 1200.0], "dwells_s": [5.0], "repeats": 1},
                     "fleet": {"visits": 10, "wear_um_per_1000h": 1.5, "adjust_at": [6]}}, seed=1)


def twin_truth(sim) -> pd.Series:
    """True lost motion per visit: the pendulum tests' interior targets (a direct system's
    linear tests do not reverse there)."""
    t = sim.truth
    extent = t.groupby("test_id")["target"].agg(["min", "max"])
    lo, hi = (t["test_id"].map(extent[c]) for c in ("min", "max"))
    inner = (t["target"] > lo) & (t["target"] < hi) & (t["method"] == "pendulum")
    return t[inner].groupby("visit")["true_backlash_um"].mean()


def test_twin_direct_series_is_the_true_lost_motion_and_not_half_of_it(direct_twin):
    table = visit_backlash(direct_twin.readings).set_index("visit")
    truth = twin_truth(direct_twin).loc[table.index]
    assert (table["target_kind"] == "paper").all()
    error = table["backlash_um"] - truth
    assert (error.abs() < 3 * table["backlash_u_um"]).all(), error.round(3).to_dict()
    share = table["reversal_mean_um"].abs() / truth  # the old series, |B_mean|
    assert share.between(0.4, 0.7).all(), share.round(2).to_dict()


def test_twin_drift_follows_the_lost_motion(direct_twin):
    (series,) = drift.analyse_visits(visit_backlash(direct_twin.readings))
    j = series.to_dict()
    assert j["change_points"] == ["06"]                 # the adjustment
    truth = twin_truth(direct_twin).loc["06":]
    dates = direct_twin.visits.set_index("visit").loc[truth.index, "started_at"]
    slope = np.polyfit(months_between(dates, dates.iloc[0]), truth.to_numpy(), 1)[0]
    low, high = j["slope_interval"]
    assert low <= slope <= high
    assert j["slope_um_per_month"] == pytest.approx(slope, rel=0.2)


def test_fleet_adjustments_are_found_in_the_lost_motion_series():
    """The fleet preset (direct system, 4 machines x 3 axes, nut re-adjusted at visit 5): the
    series steps down at the true adjustment on every axis and nowhere else (the diluted
    |B_mean| series, half as high with the same scatter, found none of them)."""
    from models.physics.campaign import simulate
    from models.wear.wear_clock import found_adjustments

    sim = simulate("fleet", seed=0)
    found = found_adjustments(visit_backlash(sim.readings))
    events = sim.visits[sim.visits["event"] == "adjustment"]
    key = ["machine_id", "axis", "visit"]
    assert sorted(map(tuple, found[key].to_numpy().tolist())) == sorted(
        map(tuple, events[key].to_numpy().tolist()))
    assert len(found) == 12
