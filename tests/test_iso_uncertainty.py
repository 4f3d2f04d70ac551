"""``backlash iso --uncertainty``: the expanded uncertainties of the ISO 230-2 figures of the
real ecmc test, against a hand calculation of the ISO/TR 230-9 budget at its own measuring
length and runs per direction."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pandas as pd
import pytest

import backlash as bl
from features import uncertainty as unc
from features.readings.errors import InputError
from pipeline.cli import main
from pipeline.reports.iso_chart import _box_line
from pipeline.steps.iso import JSON_KEYS

ROOT = Path(__file__).resolve().parents[1]
BUDGET = ROOT / "experiments" / "data" / "paper_uncertainty.toml"
# the outlier notes and the [paper]-arithmetic note are checked where they matter
pytestmark = pytest.mark.filterwarnings("ignore::features.readings.errors.BacklashWarning")
U_KEYS = ["U_A_um", "U_E_um", "U_M_um", "U_R_um", "U_B_um"]


def hand_U(length_mm: float, n: int) -> dict:
    """The paper budget's contributors at ``length_mm`` (ISO arithmetic: every line at the
    measuring length, accuracy and wavelength stability in quadrature), written out term by
    term from ISO/TR 230-9 and the GUM, then combined as the paper's Table 4."""
    b = tomllib.loads(BUDGET.read_text(encoding="utf-8"))
    dev, tem, k = b["device"], b["temperature"], b["coverage_factor"]
    L, r3 = length_mm, math.sqrt(3.0)
    u_acc = dev["laser_accuracy_ppm"] * L * 1e-3 / r3  # ppm of L [um], half-width / sqrt 3
    u_wav = dev["wavelength_stability_ppm"] * L * 1e-3 / r3
    u_res = dev["resolution_um"] / (2 * r3)
    u_d = math.sqrt(u_acc ** 2 + u_wav ** 2 + u_res ** 2)
    gamma = math.asin(b["misalignment"]["offset_mm"] / L)
    u_m = L * 1000.0 * (1 - math.cos(gamma)) / (2 * r3)
    u_theta = tem["sensor_width_c"] / (2 * r3)
    u_alpha = tem["expansion_width_um_per_mm_c"] / (2 * r3)
    u_t = math.hypot(tem["expansion_um_per_mm_c"] * L * u_theta,
                     abs(tem["machine_temperature_c"] - 20.0) * L * u_alpha)
    u_eve = b["environment"]["drift_um"] / (2 * r3)
    u_s = math.sqrt(2) * b["setup"]["abbe_offset_mm"] * 1e-3 \
        * b["setup"]["angular_deviation_um_per_m"] / (2 * r3)
    fixed = u_d ** 2 + u_m ** 2 + u_t ** 2 + u_s ** 2
    u_b2 = (2 * u_s) ** 2 + (2 * u_eve) ** 2 / n
    return {"U_A_um": k * math.sqrt(fixed + (8 + 3 / n) * u_eve ** 2),
            "U_E_um": k * math.sqrt(fixed + u_eve ** 2 / n),
            "U_M_um": k * math.sqrt(fixed + u_eve ** 2 / (2 * n)),
            "U_R_um": k * math.sqrt(u_b2 + (2 * u_eve) ** 2),
            "U_B_um": k * math.sqrt(u_b2)}


def ess_targets(path) -> list[float]:
    """The ESS file's targets, read from its text (``TGT_DATA[i]=value``)."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    return [float(ln.split("=", 1)[1].split()[0]) for ln in lines if ln.startswith("TGT_DATA")]


def test_ess_U_equal_the_hand_calculation(ess_file, capsys):
    targets = ess_targets(ess_file)
    length = max(targets) - min(targets)
    assert length == pytest.approx(40.8)  # 15 mm to 55.8 mm, five runs per direction
    want = hand_U(length, 5)
    assert main(["iso", str(ess_file), "--json", "--uncertainty", str(BUDGET)]) == 0
    out = capsys.readouterr()
    (test,) = json.loads(out.out)
    assert list(test) == [*JSON_KEYS, *U_KEYS, "per_target"]
    for key in U_KEYS:
        assert test[key] == pytest.approx(want[key], rel=1e-12), key
    # B and R differ in their direction-independent parts only: U(B) is the paper's 4.12 um
    assert round(test["U_B_um"], 2) == 4.12
    header, row = out.err.splitlines()[:2]
    assert header.split()[-5:] == U_KEYS
    assert row.split()[-5:] == [f"{want[k]:.3f}" for k in U_KEYS]
    assert "ISO arithmetic at each test's measuring length" in out.err  # the [paper] note


def test_dropped_outliers_lower_the_runs_and_widen_U(ess_file):
    # both outliers are + readings of cycle 1: two targets keep 4 runs up
    result = bl.iso(ess_file, drop_outliers=True, uncertainty=str(BUDGET))
    got = result.figures.iloc[0]
    want = hand_U(40.8, 4)
    for key in U_KEYS:
        assert got[key] == pytest.approx(want[key], rel=1e-12), key
    assert got["U_B_um"] > bl.iso(ess_file, uncertainty=BUDGET).figures.iloc[0]["U_B_um"]


def test_a_loaded_budget_or_a_dict_gives_the_same_U(ess_file):
    by_path = bl.iso(ess_file, uncertainty=BUDGET).figures[U_KEYS]
    loaded = unc.read_budget(BUDGET)
    table = tomllib.loads(BUDGET.read_text(encoding="utf-8"))
    for source in (loaded, table):
        pd.testing.assert_frame_equal(bl.iso(ess_file, uncertainty=source).figures[U_KEYS],
                                      by_path)
    assert loaded.length_mm == 360.0 and loaded.cycles == 5  # the budget itself is untouched


def test_without_a_budget_nothing_changes(ess_file, capsys):
    result = bl.iso(ess_file)
    assert result.budget is None and not set(U_KEYS) & set(result.figures.columns)
    assert "U_B_um" not in result.table()
    main(["iso", str(ess_file), "--json"])
    (test,) = json.loads(capsys.readouterr().out)
    assert list(test) == [*JSON_KEYS, "per_target"]


def test_chart_shows_figure_plus_minus_U(ess_file, tmp_path, capsys):
    out = tmp_path / "ess.png"
    assert main(["iso", str(ess_file), "--uncertainty", str(BUDGET), "--plot", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    row = bl.iso(ess_file, uncertainty=BUDGET).figures.iloc[0]
    assert _box_line(row, "B") == f"B  {row['B']:9.3f} ± {row['U_B_um']:.3f}"
    assert _box_line(row, "B_mean") == f"B̄  {row['B_mean']:9.3f}"  # ISO 230-2's symbol


def negative_budget(tmp_path) -> Path:
    path = tmp_path / "negative.toml"
    path.write_text(BUDGET.read_text(encoding="utf-8").replace("drift_um = 1.0",
                                                               "drift_um = -1.0"))
    return path


@pytest.mark.parametrize("budget, words", [
    ("missing.toml", "no such file"),
    ("negative", "'environment.drift_um': a contributor cannot be negative"),
])
def test_bad_budget_is_one_line_and_writes_nothing(ess_file, tmp_path, capsys, budget, words):
    budget = negative_budget(tmp_path) if budget == "negative" else tmp_path / budget
    chart = tmp_path / "charts" / "chart.png"
    code = main(["iso", str(ess_file), "--json", "--plot", str(chart),
                 "--uncertainty", str(budget)])
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0] and budget.name in err[0], err
    assert captured.out == "" and not chart.parent.exists()


def test_a_loaded_budget_is_checked_too(ess_file, tmp_path):
    budget = unc.read_budget(BUDGET)
    budget.environment.drift_um = -1.0
    with pytest.raises(InputError, match="cannot be negative"):
        bl.iso(ess_file, uncertainty=budget)
    with pytest.raises(InputError, match="uncertainty") as err:
        bl.iso(ess_file, uncertainty=3.0)
    assert err.value.parameter == "uncertainty"


def test_rotary_axis_refuses_a_budget(tmp_path, capsys):
    from tests.test_iso230 import synthetic

    path = tmp_path / "rotary.csv"
    synthetic(1, seed=2, axis="C").to_csv(path, index=False)
    with pytest.raises(InputError, match="rotary axis C") as err:
        bl.iso(path, uncertainty=BUDGET)
    assert err.value.parameter == "uncertainty"
    assert main(["iso", str(path), "--json", "--uncertainty", str(BUDGET)]) == 2
    captured = capsys.readouterr()
    err_lines = captured.err.strip().splitlines()
    assert len(err_lines) == 1 and "--uncertainty" in err_lines[0], err_lines
    assert captured.out == ""
