"""Feature ranking on synthetic data whose drivers are known."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from features import ranking
from features.readings.errors import InputError
from features.readings.fileio import clean_nan, dumps

DRIVERS = ("target", "feed_mm_min")
NON_DRIVERS = ("humidity_pct", "pressure_hpa")


def conditions(n: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    return pd.DataFrame({
        "target": rng.choice(np.linspace(25.0, 325.0, 7), n),
        "feed_mm_min": rng.choice([200.0, 500.0, 1200.0], n),
        "machine_temp_c": rng.normal(22.0, 1.0, n),
        "pressure_hpa": rng.normal(1013.0, 5.0, n),
        "humidity_pct": rng.normal(45.0, 8.0, n),
    })


def known_backlash(X: pd.DataFrame, seed: int) -> pd.Series:
    """Backlash [um] from position (wear grows along the axis) and feed (windup) only."""
    noise = np.random.default_rng(seed + 1).normal(0.0, 0.3, len(X))
    return 2.0 + 0.008 * X["target"] + 0.0015 * X["feed_mm_min"] + noise


@pytest.fixture(scope="module")
def truth():
    X = conditions(240, seed=3)
    y = known_backlash(X, seed=3)
    return X, y, ranking.rank_features(X, y, n_boot=100, n_repeats=3)


@pytest.mark.parametrize("score", ["anova_score", "permutation_um", "mutual_info", "knn_drop"])
def test_drivers_score_above_non_drivers(truth, score):
    table = truth[2].table
    assert table.loc[list(DRIVERS), score].min() > table.loc[list(NON_DRIVERS), score].max()


def test_final_rank_and_influence_follow_the_truth(truth):
    table = truth[2].table
    assert set(table.index[:2]) == set(DRIVERS)
    assert list(table["rank"]) == [1, 2, 3, 4, 5]
    assert table.loc[list(DRIVERS), "influence"].all()
    assert not table.loc[list(NON_DRIVERS), "influence"].any()
    assert "no measurable association" in table.loc["humidity_pct", "reading"]
    assert "is associated with backlash" in table.loc["feed_mm_min", "reading"]
    for reading in table["reading"]:  # association only: no physics claimed here
        assert "drives" not in reading and "Edlen" not in reading


def test_physical_readings_come_from_the_effect_records(truth):
    """The physics of each verdict is the effect records' reading (models.influence)."""
    from models.influence import conditional_influence
    from models.physics.effects import EFFECTS

    X, y, result = truth
    table = conditional_influence(X, y, association=result.table["influence"], n_boot=20).table
    assert "no measurable influence" in table.loc["humidity_pct", "physical_reading"]
    assert "backlash_feed" in table.loc["feed_mm_min", "physical_reading"]
    assert EFFECTS["backlash_feed"].reading in table.loc["feed_mm_min", "physical_reading"]
    assert "worn" in table.loc["target", "physical_reading"]  # local wear of screw and nut
    assert EFFECTS["backlash_position"].reading in table.loc["target", "physical_reading"]
    assert "air_refraction" in table.loc["humidity_pct", "physical_reading"]
    assert list(table.loc[list(DRIVERS), "verdict"]) == ["driver", "driver"]
    assert set(table.loc[list(NON_DRIVERS), "verdict"]) == {"none"}


def test_each_score_carries_a_finite_spread(truth):
    table = truth[2].table
    for col in ("anova_score_std", "permutation_std_um", "mutual_info_std", "knn_drop_std"):
        assert np.isfinite(table[col]).all() and (table[col] >= 0).all(), col
    # A driver's ANOVA score is many spreads away from zero; a non-driver's is not.
    z = table["anova_score"] / table["anova_score_std"]
    assert z["target"] > 5 and z["humidity_pct"] < 3


def test_knn_accuracy_and_confusion(truth):
    X, _, result = truth
    knn = result.knn
    assert knn.confusion.sum() == len(X)
    assert knn.confusion.shape == (4, 4)
    assert np.isclose(np.trace(knn.confusion) / len(X), knn.accuracy)  # equal folds of 48
    assert knn.accuracy > 2 * knn.majority_rate  # well above guessing the largest class
    assert knn.accuracy_std > 0 and knn.n_splits == 5
    assert list(knn.class_counts) == [60, 60, 60, 60]


def test_knn_separates_classes_that_position_alone_decides():
    X = conditions(200, seed=5)
    y = 1.0 + 0.01 * X["target"]  # classes are position bands
    classes, edges = ranking.backlash_classes(y, 3)
    knn, drop = ranking.knn_scores(X[["target", "humidity_pct"]], classes, edges)
    assert knn.accuracy == 1.0
    assert drop.loc["target", "knn_drop"] > 0.4
    assert drop.loc["humidity_pct", "knn_drop"] <= 0.0  # noise only dilutes the distance


def test_neg_log_p_is_finite_where_p_underflows():
    # For dfn = 2 the F survival function is closed form: p = (1 + 2F/d)^(-d/2).
    d = 100.0
    f_stat = np.array([3.0, 1e6, 1e10])
    expected = d / 2 * np.log1p(2 * f_stat / d)
    got = ranking.anova_neg_log_p(f_stat, 2, d)
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    assert stats.f.sf(1e10, 2, d) == 0.0  # the naive route gives p = 0, -ln(p) = inf
    assert np.isfinite(got).all() and got[-1] > -np.log(1e-300)


def test_anova_score_of_a_perfect_separator_is_finite():
    rng = np.random.default_rng(0)
    classes = np.repeat(np.arange(4), 500)
    X = pd.DataFrame({"x": classes + rng.normal(0, 1e-3, classes.size),
                      "noise": rng.normal(size=classes.size)})
    table = ranking.anova_scores(X, classes, n_boot=20)
    assert np.isfinite(table.loc["x", "anova_score"]) and table.loc["x", "anova_score"] > 690.0
    assert table.loc["noise", "anova_score"] < 10.0
    assert ranking.format_p(table.loc["x", "anova_score"]).startswith("p = ")
    assert ranking.format_p(-np.log(1e-300) + np.log(3.0)) == "p = 3.3e-301"


def test_backlash_classes_quantiles_and_boundaries():
    y = np.arange(1.0, 13.0)
    classes, edges = ranking.backlash_classes(y, 4)
    assert np.bincount(classes).tolist() == [3, 3, 3, 3]
    assert edges[0] == 1.0 and edges[-1] == 12.0
    classes, edges = ranking.backlash_classes(y, [4.5, 100.0])  # the top class is empty
    assert np.bincount(classes).tolist() == [4, 8]
    np.testing.assert_allclose(edges, [1.0, 4.5, 12.0])


def test_proxy_for_the_visit_is_named():
    X = conditions(180, seed=7)
    visit = np.repeat(["2024-01", "2024-06", "2025-01"], 60)
    X["humidity_pct"] = np.repeat([35.0, 55.0, 48.0], 60)  # one reading per visit
    wear_um = pd.Series(visit).map({"2024-01": 0.0, "2024-06": 1.5, "2025-01": 3.0})
    y = known_backlash(X, seed=7) + wear_um.to_numpy()
    result = ranking.rank_features(X, y, groups=visit, n_boot=50, n_repeats=2)
    table = result.table
    assert table.loc["humidity_pct", "proxy_for_visit"]
    assert table.loc["humidity_pct", "within_visit_share"] == pytest.approx(0.0, abs=1e-12)
    assert "stands in for the visit" in table.loc["humidity_pct", "reading"]
    assert not table.loc[["target", "feed_mm_min", "pressure_hpa"], "proxy_for_visit"].any()


def test_consensus_rank_catches_a_non_monotone_driver():
    X = conditions(240, seed=11)[["target", "pressure_hpa", "humidity_pct"]]
    # Wear peaks mid-travel: every backlash class has the same mean position.
    y = 2.0 + 3.0 * np.exp(-((X["target"] - 175.0) / 60.0) ** 2)
    y = y + np.random.default_rng(1).normal(0, 0.1, len(X))
    table = ranking.rank_features(X, y, rank_by="consensus", n_boot=50, n_repeats=2).table
    assert table.index[0] == "target"
    assert table.loc["target", "influence"]
    assert "not monotone" in table.loc["target", "reading"]
    # The paper's ANOVA order alone is blind to it: position is not significant there.
    assert table.loc["target", "anova_score"] < -np.log(ranking.ANOVA_ALPHA)
    paper = ranking.final_rank(table, "anova")
    assert paper["target"] > paper[table["anova_score"].idxmax()]


def test_prefit_predictor_with_predict_only():
    from sklearn.linear_model import LinearRegression

    X = conditions(120, seed=2)
    y = known_backlash(X, seed=2)
    used = ["target", "feed_mm_min"]
    fitted = LinearRegression().fit(X[used], y)

    class Predictor:  # like a loaded model: predicts from the columns it was trained on
        def predict(self, frame):
            return fitted.predict(frame[used])

    table = ranking.permutation_scores(X, y, Predictor(), prefit=True, n_repeats=4)
    assert (table.loc[used, "permutation_um"] > 0.3).all()
    assert (table.drop(index=used)["permutation_um"] == 0.0).all()


def test_json_is_strict_and_ordered_by_rank(truth):
    result = truth[2]
    payload = json.loads(dumps(clean_nan(result.to_dict())))
    assert 0.0 < payload["knn_accuracy"] <= 1.0
    ranks = [f["rank"] for f in payload["features"]]
    assert ranks == sorted(ranks) == [1, 2, 3, 4, 5]
    assert {"name", "anova_score", "permutation", "mutual_info", "rank"} <= set(
        payload["features"][0])


def test_same_seed_same_numbers():
    X = conditions(80, seed=4)
    y = known_backlash(X, seed=4)
    a = ranking.rank_features(X, y, n_boot=20, n_repeats=2, random_state=9).table
    b = ranking.rank_features(X, y, n_boot=20, n_repeats=2, random_state=9).table
    pd.testing.assert_frame_equal(a, b)


# --- bad inputs -----------------------------------------------------------------------------

def test_constant_backlash_is_a_single_class():
    X = conditions(40, seed=1)
    with pytest.raises(InputError, match="one backlash class") as err:
        ranking.rank_features(X, np.full(40, 3.0))
    assert err.value.column == "backlash_um"


def test_boundaries_leaving_one_class():
    X = conditions(40, seed=1)
    with pytest.raises(InputError, match="one backlash class"):
        ranking.rank_features(X, known_backlash(X, 1), bins=[100.0])


def test_constant_input_is_named():
    X = conditions(40, seed=1).assign(pressure_hpa=1013.25)
    with pytest.raises(InputError, match="constant") as err:
        ranking.rank_features(X, known_backlash(X, 1))
    assert err.value.column == "pressure_hpa"
    assert "pressure_hpa" in err.value.line()


def test_fewer_points_than_k():
    X = conditions(4, seed=1)
    with pytest.raises(InputError, match=r"only 4 points but k = 5"):
        ranking.rank_features(X, [1.0, 2.0, 3.0, 4.0])


def test_training_fold_smaller_than_k():
    X = conditions(12, seed=1)
    with pytest.raises(InputError, match="training fold holds"):
        ranking.rank_features(X, known_backlash(X, 1), n_neighbors=10)


def test_nan_in_features_is_named():
    X = conditions(40, seed=1)
    X.loc[7, "humidity_pct"] = np.nan
    with pytest.raises(InputError, match="NaN") as err:
        ranking.rank_features(X, known_backlash(X, 1))
    assert err.value.column == "humidity_pct"
    assert "point 8" in err.value.line()


def test_nan_backlash_is_named():
    X = conditions(40, seed=1)
    y = known_backlash(X, 1).to_numpy().copy()
    y[3] = np.nan
    with pytest.raises(InputError, match="point 4") as err:
        ranking.rank_features(X, y)
    assert err.value.column == "backlash_um"


def test_class_with_one_point():
    X = conditions(40, seed=1)
    y = known_backlash(X, 1).to_numpy()
    with pytest.raises(InputError, match="single point"):
        ranking.rank_features(X, y, bins=[np.sort(y)[-1]])


def test_unknown_rank_rule():
    X = conditions(40, seed=1)
    with pytest.raises(InputError, match="unknown rank rule"):
        ranking.rank_features(X, known_backlash(X, 1), rank_by="votes")


def test_twin_drivers_rank_above_inputs_without_effect():
    """Twin truth: backlash grows with feed and has a wear bump along the axis; humidity,
    pressure, ambient and dwell have no effect on it."""
    from features.table import feature_table
    from models.physics.campaign import simulate

    effects = {"backlash": {"b0_um": 1.5}, "backlash_position": {"amplitude_um": 1.5},
               "backlash_feed": {"k_um_per_m_min": 1.2}, "lead_error_linear": {}}
    table = feature_table(simulate({"effects": effects}, seed=5).readings)
    result = ranking.rank_features(table.X, table.y, n_boot=30, random_state=0)
    rank = result.table["rank"]
    drivers = max(rank["feed_mm_min"], rank["target"])
    for idle in ("humidity_pct", "pressure_hpa", "ambient_temp_c", "dwell_s"):
        assert rank[idle] > drivers, (idle, rank.to_dict())
    assert not result.table.loc[["humidity_pct", "dwell_s"], "influence"].any()


# --- the command ----------------------------------------------------------------------------

def test_rank_command_json_has_verdicts_and_headline_lists_only_drivers(tmp_path, capsys):
    """Twin data (paper plan, one repeat): JSON keeps the association keys and adds the
    verdicts; the report's headline names the drivers and nothing else."""
    from pipeline.cli import main
    from pipeline.workflows.simulate import simulate

    simulate({"plan": {"repeats": 1}}, preset="paper", seed=3).write(tmp_path / "t")
    code = main(["rank", str(tmp_path / "t" / "readings.csv"), "--out", str(tmp_path / "r"),
                 "--boot", "10", "--no-dropcolumn", "--json"])
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    features = {f["name"]: f for f in payload["features"]}
    for f in features.values():
        assert {"anova_score", "permutation", "mutual_info", "rank", "reading", "verdict",
                "effect_um", "effect_interval_um", "proxy_for"} <= set(f)
        assert f["verdict"] in ("driver", "proxy", "none", "undecided")
    for idle in ("pressure_hpa", "humidity_pct", "ambient_temp_c", "dwell_s"):
        assert features[idle]["verdict"] != "driver"
    assert features["feed_mm_min"]["verdict"] == "driver"
    low, high = features["feed_mm_min"]["effect_interval_um"]
    assert low < 1.2 < high  # backlash_feed: 1.2 um per m/min over 0.2-1.2 m/min
    assert payload["drivers"] == [f["name"] for f in payload["features"]
                                  if f["verdict"] == "driver"]
    page = (tmp_path / "r" / "rank_report.html").read_text(encoding="utf-8")
    headline = page.split('<div class="summary">')[1].split("</div>")[0]
    for name, f in features.items():
        assert (f"<b>{f['label']}</b>" in headline) == (f["verdict"] == "driver"), name


def test_rank_command_refuses_negative_boot(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["rank", "missing.csv", "--out", str(tmp_path), "--boot", "-1"]) == 2  # refused by the option's type, before any work
    assert "--boot" in (err := capsys.readouterr().err) and "expected an int in the range [0, inf)" in err


def test_paper_replication_experiment_names_only_known_options():
    """Every step of the replication experiment is a job and every value it sets is one of
    that job's keyword parameters (or ``out``); outputs lie inside {out}."""
    import inspect
    import tomllib
    from pathlib import Path

    from pipeline.workflows import workflow

    path = Path(__file__).resolve().parents[1] / "experiments" / "paper_replication.toml"
    spec = tomllib.loads(path.read_text(encoding="utf-8"))
    jobs = [step["job"] for step in spec["steps"]]
    assert jobs == ["simulate", "replicate", "rank"]
    for step in spec["steps"]:
        accepted = set(inspect.signature(workflow(step["job"]).function).parameters) | {"out"}
        assert set(step["with"]) <= accepted, (step["job"], set(step["with"]) - accepted)
        assert step["with"]["out"].startswith("{out}/")
    config = path.parent / spec["steps"][0]["with"]["config"].replace("{here}/", "")
    assert config.is_file()


def test_replication_table_on_a_small_twin(tmp_path):
    """Paper plan with backlash growing along the axis: the ANOVA order is the paper's
    (position and deviations, then feed, then environment), the deviations are left out in
    the second column, and the notes say why."""
    from features.table import PAPER_FEATURES, feature_table
    from models.physics.campaign import load_config, simulate
    from pipeline import replication

    here = __import__("pathlib").Path(__file__).resolve().parents[1]
    config = load_config(here / "experiments/data/paper_replication_twin.toml", preset="paper")
    table = feature_table(simulate(config, seed=7).readings, target="paper",
                          features=list(PAPER_FEATURES))
    from sklearn.linear_model import LinearRegression

    results = replication.replicate(table.X, table.y, table.meta, n_boot=5,
                                    estimator=LinearRegression())
    order = results["with deviations"]["anova_order"]
    # position and the deviations (which follow position through the lead error) lead,
    # in either order, then feed, then the environment
    assert set(order[:3]) == {"target", *replication.DEVIATIONS}
    assert order[3] == "feed_mm_min"
    assert "deviation_up_um" not in results["without deviations"]["anova_order"]
    for case in results.values():
        assert case["verdict"]["target"] == "driver"
        assert 0 < case["network"]["best_epoch"] <= case["network"]["epochs"]
        assert case["network"]["regression_r"]["all"] > 0.8
    assert results["with deviations"]["verdict"]["deviation_up_um"] == "proxy"
    paths = replication.write_replication(results, tmp_path)
    text = paths["md"].read_text(encoding="utf-8")
    assert "| best epoch / total epochs (Fig. 10) | 27 / 33 |" in text
    assert "left out" in text and "carries the target" in text


def test_replicate_command_refuses_negative_boot(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["replicate", "missing.csv", "--out", str(tmp_path), "--boot", "-2"]) == 2  # refused by the option's type, before any work
    assert "--boot" in (err := capsys.readouterr().err) and "expected an int in the range [0, inf)" in err
    assert not any(tmp_path.iterdir())  # nothing written
