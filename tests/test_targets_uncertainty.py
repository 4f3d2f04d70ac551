"""The measurement uncertainty U of every backlash point and of every visit, from an ISO/TR 230-9
budget (``backlash_U_um``).

Known truth: hand-built tests of measuring length 120 mm, 5 runs per direction, whose
repeatability u_r is computed here from the readings; the budget's own U(B) and u_S at that
length as ``backlash uncertainty --json`` prints them.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import InputError
from features.targets import backlash_targets
from features.uncertainty import read_budget
from features.visits import axis_backlash

BUDGET = "experiments/data/paper_uncertainty.toml"
LENGTH_MM = 120.0
TARGETS = np.linspace(0.0, LENGTH_MM, 5)
CYCLES = 5
B_UM = 3.0


def tests_frame(methods=("linear",), direct: bool = False, axis: str = "X",
                seed: int = 0) -> pd.DataFrame:
    """One visit: a test per method over TARGETS, lost motion B_UM on every approach (indirect)
    or only where the test reverses (direct: the pendulum's targets, the linear's ends)."""
    rng = np.random.default_rng(seed)
    parts = []
    for method in methods:
        target, cycle, up = (a.ravel() for a in np.meshgrid(
            TARGETS, np.arange(1, CYCLES + 1), [True, False], indexing="ij"))
        shows = np.ones(target.size, bool)
        if direct and method == "linear":
            shows = (up & (target == TARGETS[-1])) | (~up & (target == TARGETS[0]))
        deviation = (np.where(up, -B_UM / 2, B_UM / 2) * shows + 0.004 * target
                     + rng.normal(0, 0.2, target.size))
        parts.append(pd.DataFrame({
            "machine_id": "M1", "axis": axis, "test_id": method, "method": method,
            "target": target, "direction": np.where(up, "+", "-"), "cycle": cycle,
            "deviation_um": deviation, "visit": "1", "repeat": 1, "feed_mm_min": 500.0,
            "dwell_s": 1.0}))
    return pd.concat(parts, ignore_index=True)


def repeatability_um(readings: pd.DataFrame, target: float) -> float:
    """u_r of one point by hand: √(Σ s²/n) over the means (test, direction) it takes."""
    at = readings[readings["target"] == target]
    s = at.groupby(["test_id", "direction"])["deviation_um"].agg(["std", "size"])
    return math.sqrt(float((s["std"] ** 2 / s["size"]).sum()))


@pytest.fixture(scope="module")
def printed(tmp_path_factory) -> dict:
    """``backlash uncertainty --json --arithmetic iso`` of the paper budget at LENGTH_MM."""
    import contextlib
    import io

    from pipeline import cli

    path = tmp_path_factory.mktemp("budget") / "at_120.toml"
    text = Path(BUDGET).read_text(encoding="utf-8")
    path.write_text(text.replace("length_mm = 360.0", f"length_mm = {LENGTH_MM}"),
                    encoding="utf-8")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli.main(["uncertainty", str(path), "--json", "--arithmetic", "iso"]) == 0
    printed = json.loads(out.getvalue())
    assert printed["length_mm"] == LENGTH_MM and printed["cycles"] == CYCLES
    return printed


def test_iso_point_is_the_budgets_U_B_with_its_repeatability(printed):
    readings = tests_frame()
    points = backlash_targets(readings, "iso", budget=BUDGET)
    k, U_B = printed["coverage_factor"], printed["U_um"]["B"]
    assert U_B == pytest.approx(4.115, abs=5e-4)  # Table 4 (the paper prints 4.12)
    for row in points.itertuples():
        u_r = repeatability_um(readings, row.target)
        assert row.backlash_u_um == pytest.approx(u_r, rel=1e-9)
        assert row.backlash_U_um == pytest.approx(k * math.hypot(U_B / k, u_r), rel=1e-9)
    assert points.attrs["coverage_factor"] == k
    assert list(points.columns).index("backlash_U_um") == \
        list(points.columns).index("backlash_u_um") + 1


def test_paper_point_keeps_the_environment_of_both_runs_not_the_abbe_setup(printed):
    readings = tests_frame(("linear", "pendulum"), direct=True)
    points = backlash_targets(readings, budget=BUDGET)
    assert points.attrs["target_kind"] == "paper"
    k, U_B = printed["coverage_factor"], printed["U_um"]["B"]
    u_setup = 2 * printed["contributors_um"]["u_S"]          # 2u_S: the same in both runs
    u_env2 = (U_B / k) ** 2 - u_setup ** 2                    # (2u_EVE)²/n of one run
    assert u_env2 == pytest.approx((2 * printed["contributors_um"]["u_EVE"]) ** 2 / CYCLES)
    for row in points.itertuples():
        u_r = repeatability_um(readings, row.target)
        assert row.backlash_U_um == pytest.approx(k * math.sqrt(2 * u_env2 + u_r ** 2),
                                                  rel=1e-9)
    np.testing.assert_allclose(points["backlash_um"], B_UM, atol=0.6)
    # the ISO reading of the same tests carries the Abbe term: U(B) at least
    iso = backlash_targets(readings, "iso", budget=BUDGET)
    assert (iso["backlash_U_um"] >= U_B).all()
    assert (points["backlash_U_um"] < 0.5 * U_B).all()


def test_without_a_budget_no_column_is_added():
    readings = tests_frame(("linear", "pendulum"), direct=True)
    assert "backlash_U_um" not in backlash_targets(readings)
    assert "coverage_factor" not in backlash_targets(readings).attrs
    assert not {"backlash_U_um", "backlash_u_visit_um"} & set(axis_backlash(readings))
    import backlash as bl

    result = bl.targets(readings)
    assert "backlash_U_um" not in result.points and result.coverage_factor is None
    assert result.to_dict()["coverage_factor"] is None


def test_each_visit_combines_its_points(printed):
    k, U_B = printed["coverage_factor"], printed["U_um"]["B"]
    u_setup = 2 * printed["contributors_um"]["u_S"]
    u_env2 = (U_B / k) ** 2 - u_setup ** 2
    for readings, setup2, env2 in ((tests_frame(), u_setup ** 2, u_env2),
                                   (tests_frame(("linear", "pendulum"), direct=True), 0.0,
                                    2 * u_env2)):
        visit = axis_backlash(readings, budget=BUDGET).iloc[0]
        u_r = visit["backlash_u_um"]
        assert visit["backlash_U_um"] == pytest.approx(k * math.sqrt(setup2 + env2 + u_r ** 2))
        assert visit["backlash_u_visit_um"] == pytest.approx(math.sqrt(env2 + u_r ** 2))


@pytest.mark.parametrize("case", ["dict", "object"])
def test_bad_budget_on_the_targets_is_one_line(case):
    readings = tests_frame()
    if case == "dict":
        import tomllib

        table = tomllib.loads(Path(BUDGET).read_text(encoding="utf-8"))
        table["environment"]["drift_um"] = -1.0
        with pytest.raises(InputError) as err:
            backlash_targets(readings, budget=table)
        assert "environment.drift_um" in str(err.value)
    else:
        import backlash as bl

        budget = replace(read_budget(BUDGET), cycles=1)
        with pytest.raises(InputError) as err:
            bl.targets(readings, uncertainty=budget)
        assert "cycles" in str(err.value)
    assert "\n" not in str(err.value)


def test_rotary_axis_refuses_a_budget_on_the_targets():
    with pytest.raises(InputError, match="holds lengths, not angles"):
        backlash_targets(tests_frame(axis="C"), budget=BUDGET)


def test_cli_writes_the_column(tmp_path, capsys, printed):
    from pipeline import cli

    data = tmp_path / "r.csv"
    tests_frame(("linear", "pendulum"), direct=True).to_csv(data, index=False)
    out = tmp_path / "o"
    assert cli.main(["targets", str(data), "--uncertainty", BUDGET, "--out", str(out),
                     "--json"]) == 0
    captured = capsys.readouterr()
    written = pd.read_csv(out / "targets.csv")
    printed_points = json.loads(captured.out)
    assert printed_points["coverage_factor"] == 2.0
    assert printed_points["target_kind"] == "paper" and len(printed_points["points"]) == 3
    np.testing.assert_allclose(written["backlash_U_um"],
                               [p["backlash_U_um"] for p in printed_points["points"]])
    assert "backlash_U_um" in captured.err and "k = 2" in captured.err


def test_cli_missing_budget_is_one_line_exit_2_nothing_written(tmp_path, capsys):
    from pipeline import cli

    data = tmp_path / "r.csv"
    tests_frame().to_csv(data, index=False)
    out = tmp_path / "o"
    argv = ["targets", str(data), "--uncertainty", str(tmp_path / "nope.toml"), "--out",
            str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nope.toml" in err and "Traceback" not in err
    assert not out.exists()
