"""The lost motion at reference conditions (models/condition/reference.py) against points of
known sensitivity: the fit recovers it within its stated uncertainty, refuses what the data
cannot decide, and the correction is the sensitivity times the distance to the reference."""

import numpy as np
import pandas as pd
import pytest

from models.condition.reference import AxisReference, references_of, sensitivity

CELLS = ["machine_id", "axis", "visit", "target"]
BETA_FEED, BETA_TEMP = 2e-4, 0.15  # um per mm/min, um/K


def points(seed=0, feeds=(300.0, 500.0, 900.0), temp_span=1.5, collinear=False, tests=4,
           visits=4):
    """Per-point targets of one axis: each visit runs ``tests`` tests at feeds drawn from
    ``feeds`` and machine temperatures over ``temp_span`` K; each (visit, target) has its own
    level (wear, the profile along the screw)."""
    rng = np.random.default_rng(seed)
    rows, test = [], 0
    for visit in range(visits):
        level = 2.0 + 0.3 * visit
        for _ in range(tests):
            feed = float(rng.choice(feeds))
            temp = (20.5 + temp_span * (feed - 300) / 600 if collinear
                    else 20.5 + temp_span * rng.random())
            for target in range(5):
                b = (level + 0.1 * target + BETA_FEED * feed + BETA_TEMP * temp
                     + rng.normal(0, 0.02))
                rows.append({"machine_id": "M1", "axis": "X", "visit": str(visit),
                             "target": float(target * 100), "backlash_um": b,
                             "feed_mm_min": feed, "machine_temp_c": temp, "test": test})
            test += 1
    return pd.DataFrame(rows)


@pytest.mark.parametrize("seed", range(5))
def test_sensitivities_are_recovered_within_their_uncertainty(seed):
    s = sensitivity(points(seed), CELLS)
    u = np.sqrt(np.diag(s.cov))
    assert abs(s.beta["feed_mm_min"] - BETA_FEED) < 4 * u[0]
    assert abs(s.beta["machine_temp_c"] - BETA_TEMP) < 4 * u[1]
    assert s.tests == 16


def test_what_the_data_cannot_decide_is_not_fitted():
    assert "feed_mm_min" not in sensitivity(points(feeds=(500.0,)), CELLS).beta
    assert "machine_temp_c" not in sensitivity(points(temp_span=0.05), CELLS).beta
    assert sensitivity(points(collinear=True), CELLS).beta == {}
    assert sensitivity(points(tests=1), CELLS).beta == {}  # 4 tests: too few clusters


def test_the_correction_is_the_sensitivity_times_the_distance_to_the_reference():
    p = points()
    ref = references_of(p)[("M1", "X")]
    f_ref = float(np.median(p.drop_duplicates("test")["feed_mm_min"]))  # the tests' median
    assert ref.reference == {"temp_c": 20.0, "feed_mm_min": f_ref}
    c = ref.correction([str(v) for v in range(4)])
    mean = ref.visits.mean()
    d = np.array([f_ref - mean["feed_mm_min"], 20.0 - mean["machine_temp_c"]])
    beta = np.array([ref.feed.beta["feed_mm_min"], ref.temp.beta["machine_temp_c"]])
    assert c["correction_um"] == pytest.approx(float(beta @ d))
    assert c["correction_u_um"] == pytest.approx(float(np.sqrt(d @ ref.feed.cov @ d)))
    assert sorted(c["corrected"]) == ["feed_mm_min", "machine_temp_c"]
    # a visit whose conditions are unknown (a trace day) leaves the line uncorrected
    assert ref.correction(["0", "trace"])["correction_um"] == 0.0


def test_an_axis_that_cannot_decide_takes_its_fleet_s_pooled_sensitivity():
    one_feed = points(1, feeds=(500.0,)).assign(machine_id="M2")
    refs = references_of(pd.concat([points(0), one_feed], ignore_index=True))
    m2 = refs[("M2", "X")]
    assert m2.feed.pooled and not m2.temp.pooled
    assert isinstance(m2, AxisReference)
