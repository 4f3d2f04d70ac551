"""Backlash targets and the feature table on hand-built tests with known lost motion."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import BacklashWarning, InputError
from features.table import PAPER_FEATURES, feature_table, prediction_inputs
from features.targets import backlash_targets

TARGETS = np.linspace(0, 350, 8)


def ideal_tests(direct: bool, b_um=lambda feed: 1.0 + feed / 500, drift_um: float = 0.0,
                noise_um: float = 0.05, seed: int = 0) -> pd.DataFrame:
    """Paired linear/pendulum tests at three feeds. Lost motion b shows on every approach
    (indirect) or only on the pendulum's approaches and the linear turn-around targets (direct).
    ``drift_um``: a common-mode shift of the whole pendulum run (thermal expansion between runs).
    """
    rng = np.random.default_rng(seed)
    parts = []
    for feed in (200.0, 500.0, 1200.0):
        for method in ("linear", "pendulum"):
            target, cycle, up = (a.ravel() for a in np.meshgrid(TARGETS, np.arange(1, 6),
                                                                  [True, False], indexing="ij"))
            shows = np.ones(target.size, bool)
            if direct and method == "linear":
                shows = (up & (target == TARGETS[-1])) | (~up & (target == TARGETS[0]))
            b = b_um(feed)
            deviation = (np.where(up, -b / 2, b / 2) * shows + 0.005 * target
                         + (drift_um if method == "pendulum" else 0.0)
                         + rng.normal(0, noise_um, target.size))
            parts.append(pd.DataFrame({
                "machine_id": "M1", "axis": "X", "test_id": f"{method}-{feed:g}",
                "method": method, "target": target, "direction": np.where(up, "+", "-"),
                "cycle": cycle, "deviation_um": deviation, "visit": "1", "repeat": 1,
                "feed_mm_min": feed, "dwell_s": 3.0,
                "machine_temp_c": 20.0 + feed / 1000 + rng.normal(0, 0.05, target.size)}))
    return pd.concat(parts, ignore_index=True)


def per_feed(points: pd.DataFrame) -> pd.Series:
    return points.groupby("feed_mm_min")["backlash_um"].mean()


def test_direct_system_paper_target_recovers_b_on_interior_targets():
    points = backlash_targets(ideal_tests(direct=True))
    assert points.attrs["target_kind"] == "paper" and "direct" in points.attrs["target_reason"]
    assert set(points["target"]) == set(TARGETS[1:-1])
    np.testing.assert_allclose(per_feed(points), [1.4, 2.0, 3.4], atol=0.05)
    assert (points["backlash_u_um"] < 0.1).all()


def test_indirect_system_auto_uses_the_reversal_value():
    readings = ideal_tests(direct=False)
    assert backlash_targets(readings).attrs["target_kind"] == "iso"
    np.testing.assert_allclose(per_feed(backlash_targets(readings)), [1.4, 2.0, 3.4], atol=0.05)
    # the paper's target sees nothing on an indirect system: both runs carry the same b
    assert per_feed(backlash_targets(readings, "paper")).max() < 0.1


def test_common_mode_drift_leaks_into_z_and_cancels_in_backlash():
    points = backlash_targets(ideal_tests(direct=True, drift_um=2.0), "paper")
    assert points["z_up_um"].mean() == pytest.approx(2.0 - 6.8 / 3 / 2, abs=0.05)
    np.testing.assert_allclose(per_feed(points), [1.4, 2.0, 3.4], atol=0.05)


def test_feature_table_layout_and_iso_leaves_out_deviations():
    with pytest.warns(BacklashWarning, match="dwell_s constant over all points; left out"):
        paper = feature_table(ideal_tests(direct=True))
    assert list(paper.X.columns) == ["target", "deviation_down_um", "deviation_up_um",
                                     "feed_mm_min", "machine_temp_c"]  # dwell_s constant: left out
    assert len(paper.X) == len(paper.y) == len(paper.meta) == 3 * 6
    with pytest.warns(BacklashWarning, match="inputs without deviation_down_um, "
                      "deviation_up_um.*ISO target"):
        iso = feature_table(ideal_tests(direct=False))
    assert iso.target_kind == "iso" and "deviation_up_um" not in iso.X
    chosen = feature_table(ideal_tests(direct=True), features=["target", "feed_mm_min"])
    assert list(chosen.X.columns) == ["target", "feed_mm_min"]
    assert set(PAPER_FEATURES) >= {"target", "humidity_pct"}


def test_prediction_inputs_need_only_linear_tests():
    readings = ideal_tests(direct=True)
    inputs = prediction_inputs(readings[readings["method"] == "linear"],
                               ["target", "deviation_up_um", "feed_mm_min"])
    assert len(inputs) == 3 * 6 and inputs["deviation_up_um"].notna().all()


def test_unpaired_test_is_named():
    readings = ideal_tests(direct=True)
    readings = readings[readings["test_id"] != "pendulum-500"]
    with pytest.raises(InputError, match="unpaired linear test 'linear-500'"):
        backlash_targets(readings, "paper")


def test_two_tests_with_the_same_pair_keys_are_refused():
    readings = ideal_tests(direct=True)
    readings.loc[readings["test_id"] == "linear-500", "feed_mm_min"] = 200.0
    with pytest.raises(InputError, match="share machine, axis, visit, feed"):
        backlash_targets(readings, "paper")


def test_unknown_feature_and_target_kind():
    with pytest.raises(InputError, match="unknown feature 'speed'") as err:
        feature_table(ideal_tests(direct=True), features=["speed"])
    assert err.value.parameter == "features"
    with pytest.raises(InputError, match="unknown target 'pendulum'") as err:
        backlash_targets(ideal_tests(direct=True), "pendulum")
    assert err.value.parameter == "kind"


def test_library_errors_and_notes_name_python_parameters_not_options():
    """Errors name the caller's parameter (the CLI maps it to its option); no text in
    features/ names an option or prints."""
    from pathlib import Path

    from features.table import check_features

    X = pd.DataFrame({"target": [1.0, 2.0], "feed_mm_min": [500.0, 500.0]})
    with pytest.raises(InputError, match="constant") as err:
        check_features(X, "data.csv")
    assert err.value.parameter == "features" and "--" not in err.value.message
    root = Path(__file__).resolve().parents[1] / "features"
    for path in root.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert "print(" not in text, path
        assert "sys.stderr" not in text, path


def test_feature_table_meta_keeps_each_points_date():
    """The points' dates survive the join with their inputs (both carry one), so a forward
    split orders visits by date."""
    import backlash as bl
    from features.table import feature_table

    readings = bl.read("experiments/data/twin/readings.csv")
    table = feature_table(readings)
    assert table.meta["started_at"].notna().all()
    first = readings.groupby("visit")["started_at"].min()
    assert (table.meta.groupby("visit")["started_at"].min() >= first.loc[
        table.meta["visit"].unique()].to_numpy()).all()
