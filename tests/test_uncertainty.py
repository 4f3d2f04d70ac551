"""The ISO/TR 230-9 uncertainty budget: every number of the backlash paper's Tables 3 and 4, the
ISO arithmetic beside it, the CLI's JSON, and each bad budget as one error line with exit 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from features import uncertainty as unc
from features.readings.errors import InputError
from pipeline.workflows import workflow
from pipeline.workflows.uncertainty import UncertaintyResult, uncertainty

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "experiments" / "data" / "paper_uncertainty.toml"

# Table 3 as printed (value, decimals printed).
TABLE3 = {
    "L": (360, 0), "a": (3.4, 1), "u_accuracy": (0.1963, 4), "wavelength": (0.04, 2),
    "u_wavelength": (0.0023, 4), "u_device_estimate": (0.1986, 4), "r": (0.1, 1),
    "u_resolution": (0.0289, 4), "u_D": (0.2007, 4), "d": (1, 0), "gamma": (0.2865, 4),
    "delta_L_m": (2.5000, 4), "u_M": (0.7217, 4), "sensor": (0.7, 1), "u_theta": (0.2021, 4),
    "u_M_machine": (0.4850, 4), "u_M_device": (0, 0), "T_M": (24, 0), "delta_T": (4, 0),
    "u_alpha": (0.0006, 4), "u_E_machine": (0.4619, 4), "u_E_device": (0, 0),
    "u_T": (0.6697, 4), "E_VE": (1, 0), "u_EVE": (0.2887, 4), "O_ABBE": (50, 0),
    "D_angle": (50, 0), "delta_L_S": (3.5355, 4), "u_S": (1.0206, 4), "u_P": (1.4610, 4),
}
# Table 4 as printed [um].
TABLE4 = {"R_dir": 1.15, "B": 4.12, "R": 4.27, "E": 2.88, "M": 2.87, "A": 3.33}


@pytest.fixture(scope="module")
def paper() -> UncertaintyResult:
    return uncertainty(PAPER)


# --------------------------------------------------------------------------- the paper's numbers
@pytest.mark.parametrize("key", TABLE3)
def test_every_number_of_table_3(paper, key):
    value, decimals = TABLE3[key]
    lines = {ln.key: ln for ln in paper.values.lines}
    assert round(lines[key].value, decimals) == pytest.approx(value, abs=1e-12), key
    assert lines[key].formula and lines[key].distribution and lines[key].source


@pytest.mark.parametrize("key", TABLE4)
def test_every_number_of_table_4(paper, key):
    assert round(paper.expanded_um[key], 2) == pytest.approx(TABLE4[key], abs=1e-12), key


def test_the_paper_file_reports_the_paper_arithmetic_with_iso_beside_it(paper):
    assert paper.arithmetic == "paper" and paper.other.arithmetic == "iso"
    assert round(paper.u_p_um, 4) == 1.4610
    iso = {ln.key: ln.value for ln in paper.other.lines}
    # ISO: every length-dependent line at the measuring length, accuracy and wavelength in RSS
    assert iso["u_accuracy"] == pytest.approx(3.4 * 0.360 / math.sqrt(3))
    assert iso["u_device_estimate"] == pytest.approx(math.hypot(iso["u_accuracy"],
                                                                iso["u_wavelength"]))
    assert iso["delta_L_m"] == pytest.approx(1.0 ** 2 / (2 * 360) * 1e3, rel=1e-5)
    assert iso["u_M_machine"] == pytest.approx(0.012 * 360 * 0.7 / (2 * math.sqrt(3)))
    assert iso["u_E_machine"] == pytest.approx(4 * 360 * 0.002 / (2 * math.sqrt(3)))
    assert paper.other.u_p_um > paper.u_p_um  # the paper's shorter lengths understate u_P


def test_iso_is_the_default_arithmetic():
    table = _paper_table()
    del table["arithmetic"]
    result = uncertainty(table)
    assert result.arithmetic == "iso" and result.other.arithmetic == "paper"
    del table["paper"]
    alone = uncertainty(table)
    assert alone.other is None and alone.u_p_um == pytest.approx(result.u_p_um)
    assert uncertainty(PAPER, arithmetic="iso").u_p_um == pytest.approx(result.u_p_um)


def test_formulas():
    assert unc.rectangular_width(1.0) == pytest.approx(0.2886751, abs=1e-7)
    assert unc.resolution_uncertainty_um(0.1) == pytest.approx(0.1 / math.sqrt(12))
    assert unc.cosine_error_um(1.0, 200.0) == pytest.approx(2.5, rel=1e-5)  # d²/(2L)
    assert unc.abbe_error_um(50.0, 50.0) == pytest.approx(2.5 * math.sqrt(2))
    u = unc.expanded_parameters_um(0.2, 0.7, 0.6, 0.3, 1.0, cycles=5, k=2)
    assert u["R"] ** 2 == pytest.approx(u["B"] ** 2 + u["R_dir"] ** 2)  # R adds R↑ to B
    assert u["M"] < u["E"] < u["A"]  # M averages 2n readings; A adds the repeatability


def test_write_and_workflow_record(tmp_path, paper):
    files = paper.write(tmp_path / "out")
    saved = json.loads(files["json"].read_text(encoding="utf-8"))
    assert saved["U_um"]["B"] == pytest.approx(paper.expanded_um["B"])
    record = workflow("uncertainty")
    assert record.name == "uncertainty" and record.inputs == ("budget",)
    assert record.function is uncertainty


# --------------------------------------------------------------------------- the CLI
@pytest.fixture
def cli(monkeypatch, tmp_path):
    """``pipeline.cli.main`` run from an empty folder (so nothing can land in the repo)."""
    from pipeline import cli as cli_module

    monkeypatch.chdir(tmp_path)
    return cli_module.main


def test_cli_json_keys(cli, capsys):
    assert cli(["uncertainty", str(PAPER), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"contributors_um", "u_P_um", "U_um"} <= set(out)
    assert set(out["U_um"]) == {"R_dir", "B", "R", "E", "M", "A"}
    assert {"u_D", "u_M", "u_T", "u_EVE", "u_S"} <= set(out["contributors_um"])
    assert round(out["u_P_um"], 4) == 1.4610
    assert {k: round(v, 2) for k, v in out["U_um"].items()} == TABLE4
    assert set(out["side_by_side"]) == {"paper", "iso"}


def test_cli_table(cli, capsys):
    assert cli(["uncertainty", str(PAPER)]) == 0
    out = capsys.readouterr().out
    assert "1.4610" in out and "4.12" in out and "reported: paper" in out


def _paper_table() -> dict:
    import tomllib

    return tomllib.loads(PAPER.read_text(encoding="utf-8"))


def _budget(tmp_path, old: str | None, new: str = "", drop_table: str | None = None) -> Path:
    text = PAPER.read_text(encoding="utf-8")
    if old is not None:
        assert old in text, old
        text = text.replace(old, new)
    if drop_table:
        head, found, rest = text.partition(f"\n[{drop_table}]\n")
        assert found, drop_table
        end = rest.find("\n[")
        text = head + ("\n" + rest[end:] if end >= 0 else "\n")
    path = tmp_path / "budget.toml"
    path.write_text(text, encoding="utf-8")
    return path


BAD = {
    "missing contributor": (("drift_um = 1.0", ""), "missing key 'environment.drift_um'"),
    "missing table": ((None, "", "setup"), "missing key 'setup'"),
    "negative contributor": (("resolution_um = 0.1", "resolution_um = -0.1"),
                             "'device.resolution_um': a contributor cannot be negative"),
    "ppm where um belongs": (("resolution_um = 0.1", 'resolution_um = "0.5 ppm"'),
                             "'device.resolution_um': expected a number in um, got '0.5 ppm'"),
    "wrong unit suffix": (("laser_accuracy_ppm = 3.4", "laser_accuracy_um = 3.4"),
                          ("'device.laser_accuracy_um': wrong unit: 'laser_accuracy' is given "
                           "in ppm")),
    "um key given in ppm": (("drift_um = 1.0", "drift_ppm = 1.0"),
                            "'environment.drift_ppm': wrong unit"),
    "one cycle": (("cycles = 5 ", "cycles = 1 "), "'cycles': must be at least 2"),
    "zero length": (("length_mm = 360.0", "length_mm = 0.0"), "'length_mm': must be > 0"),
    "paper without its table": ((None, "", "paper"), "needs a [paper] table"),
    "unknown key": (("offset_mm = 1.0", "offset_mm = 1.0\nofset_mm = 2.0"),
                    "unknown key 'misalignment.ofset_mm'"),
    # beyond any physical value: the lines' squares would overflow (OverflowError, inf U)
    "huge length": (("length_mm = 360.0", "length_mm = 1e308"),
                    "'length_mm': must be at most 1e+09 in its unit; got 1e+308"),
    "huge drift": (("drift_um = 1.0", "drift_um = 1e308"),
                   "'environment.drift_um': must be at most 1e+09"),
    "huge Abbe offset": (("abbe_offset_mm = 50.0", "abbe_offset_mm = 1e200"),
                         "'setup.abbe_offset_mm': must be at most 1e+09"),
    "huge coverage factor": (("coverage_factor = 2.0", "coverage_factor = 1e300"),
                             "'coverage_factor': must be at most 1e+09"),
    "huge paper length": (("device_length_mm = 100.0", "device_length_mm = 1e308"),
                          "'paper.device_length_mm': must be at most 1e+09"),
    "huge cycles": (("cycles = 5 ", "cycles = 1e308 "), "'cycles': must be at most 1000000"),
    "infinite length": (("length_mm = 360.0", "length_mm = inf"),
                        "'length_mm': expected a number (finite)"),
    "NaN contributor": (("resolution_um = 0.1", "resolution_um = nan"),
                        "'device.resolution_um': expected a number (finite)"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_budget_is_one_line_exit_2_nothing_written(case, cli, capsys, tmp_path):
    (old, new, *drop), expected = BAD[case]
    path = _budget(tmp_path, old, new, drop[0] if drop else None)
    before = sorted(tmp_path.rglob("*"))
    assert cli(["uncertainty", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("backlash uncertainty: error: "), lines
    assert expected in lines[0] and "budget.toml" in lines[0], lines[0]
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("case", BAD)
def test_bad_budget_in_python(case, tmp_path):
    (old, new, *drop), expected = BAD[case]
    path = _budget(tmp_path, old, new, drop[0] if drop else None)
    with pytest.raises(InputError, match=None) as err:
        uncertainty(path)
    assert expected in str(err.value) and err.value.file == str(path)


def test_missing_file_and_bad_parameter(cli, capsys, tmp_path):
    assert cli(["uncertainty", str(tmp_path / "none.toml")]) == 2
    assert "no such file" in capsys.readouterr().err
    import backlash as bl  # the runner checks a call against the job's table

    with pytest.raises(InputError) as err:
        bl.uncertainty(PAPER, arithmetic="gum")
    assert err.value.parameter == "arithmetic"
    with pytest.raises(InputError) as err:
        bl.uncertainty(360.0)
    assert err.value.parameter == "budget"
    table = _paper_table()
    del table["paper"]
    with pytest.raises(InputError, match=r"needs a \[paper\] table"):
        uncertainty(table)
    del table["arithmetic"]
    with pytest.raises(InputError, match=r"needs the budget's \[paper\] table") as err:
        uncertainty(table, arithmetic="paper")
    assert err.value.parameter == "arithmetic"


def test_the_digest_follows_the_values_not_the_file(tmp_path):
    """A report prints the budget's digest: comments and the name leave it, a value moves it."""
    from features.uncertainty import read_budget

    paper = read_budget(PAPER)
    same = _budget(tmp_path, "drift_um = 1.0 ", "drift_um = 1.0   # re-measured, same value ")
    renamed = PAPER.read_text(encoding="utf-8").replace("name = ", "name = 'other' #")
    (tmp_path / "renamed.toml").write_text(renamed, encoding="utf-8")
    assert read_budget(same).digest() == paper.digest() == read_budget(
        tmp_path / "renamed.toml").digest()
    moved = read_budget(_budget(tmp_path, "drift_um = 1.0 ", "drift_um = 1.1 "))
    assert moved.digest() != paper.digest() and len(paper.digest()) == 12
