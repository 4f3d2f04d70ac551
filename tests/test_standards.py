"""``iso --standard``: the records of the standards the backlash paper names, the supported
one against the hand calculation of the real ecmc file, the others refused with their reason."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import backlash as bl
from features import iso230, standards
from features.readings.errors import InputError
from pipeline.cli import main
from tests.test_iso230 import hand_calculation

DOCS = Path(__file__).resolve().parents[1] / "docs" / "iso.md"
UNSUPPORTED = [s.name for s in standards.STANDARDS if not s.supported]


def test_the_paper_names_four_standards_and_iso_is_the_supported_one():
    assert standards.NAMES == ("iso230-2", "vdi3441", "asme-b5.54", "jis-b6336")
    assert [s.name for s in standards.STANDARDS if s.supported] == ["iso230-2"]
    assert standards.standard("iso230-2").figures == iso230.AXIS_FIGURES
    assert all(s.reason for s in standards.STANDARDS if not s.supported)


def test_iso_standard_equals_the_hand_calculation(ess_file, capsys):
    want = hand_calculation(ess_file)
    assert main(["iso", str(ess_file), "--standard", "iso230-2", "--json"]) == 0
    (test,) = json.loads(capsys.readouterr().out)
    for key in standards.ISO230_2.figures:
        assert test[key] == pytest.approx(want[key], rel=1e-9, abs=1e-9), key
    # by hand from the .dat text (um): B = |B_i| at 55.8 mm = |-0.229 - 43.230|; A spans
    # the + band at 15 mm, 4 s_up = 4 * 51.190 (the 93.2 um outlier kept)
    assert round(test["B"], 3) == 43.459 and round(test["A"], 3) == 204.759


@pytest.mark.parametrize("name", UNSUPPORTED)
def test_an_unsupported_standard_is_one_line_with_its_reason(ess_file, tmp_path, capsys, name):
    chart = tmp_path / "charts" / "chart.png"
    assert main(["iso", str(ess_file), "--json", "--plot", str(chart),
                 "--standard", name]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    record = next(s for s in standards.STANDARDS if s.name == name)
    assert len(err) == 1 and "--standard" in err[0] and record.reason in err[0], err
    assert "not supported" in err[0] and captured.out == "" and not chart.parent.exists()
    with pytest.raises(InputError, match="not supported") as caught:
        bl.iso(ess_file, standard=name)
    assert caught.value.parameter == "standard"


def test_an_unknown_standard_is_one_line(ess_file, capsys):
    assert main(["iso", str(ess_file), "--standard", "iso230-9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice: 'iso230-9'" in err[0]
    with pytest.raises(InputError, match="standard"):
        standards.standard("iso230-9")


def test_docs_table_and_help_come_from_the_records(capsys):
    assert standards.standards_table() in DOCS.read_text(encoding="utf-8")
    assert main(["iso", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "vdi3441 (not supported)" in text and "default iso230-2" in text


def test_several_files_equal_each_alone(ess_file, psi_file, capsys):
    assert main(["iso", str(ess_file), str(psi_file), "--json"]) == 0
    both = json.loads(capsys.readouterr().out)
    alone = []
    for path in (ess_file, psi_file):
        main(["iso", str(path), "--json"])
        alone += json.loads(capsys.readouterr().out)
    assert sorted(both, key=lambda t: t["test_id"]) == sorted(alone, key=lambda t: t["test_id"])
    result = bl.iso([ess_file, psi_file])
    assert result.sources[("psi_sls_stepper", "X", "1", "psi_sls_stepper_ISO230")] == str(psi_file)


def test_the_same_test_in_two_files_is_refused(ess_file, capsys):
    assert main(["iso", str(ess_file), str(ess_file), "--json"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "is also in" in err[0] and captured.out == ""
    with pytest.raises(InputError, match="expected one or more"):
        bl.iso([])
