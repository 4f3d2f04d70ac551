"""The readings workflows from Python (read, validate, write, convert, iso), the input-layout
records behind every --format option, and the bad inputs they refuse in one line."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features import iso230
from features.readings import layouts, schema
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import build_parser, main
from pipeline.steps.parameters import readings


def small_table(cycles: int = 3) -> pd.DataFrame:
    rows = [{"machine_id": "M1", "axis": "X", "test_id": "T1", "method": "linear",
             "target": target, "direction": d, "cycle": c,
             "deviation_um": 0.01 * target + (2.0 if d == "-" else -2.0) + 0.1 * c}
            for c in range(1, cycles + 1) for d in "+-" for target in (0.0, 50.0, 100.0)]
    return pd.DataFrame(rows)


def one_error_line(capsys, command: str) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    assert err[0].startswith(f"backlash {command}: error: "), err
    return err[0]


# ------------------------------------------------------------------ one record per layout


READINGS_HELP = readings().help


def test_every_format_option_and_readings_help_come_from_the_records():
    names = tuple(record.name for record in layouts.LAYOUTS)
    assert "rtl" in names and schema.FORMATS == ("auto", *names)
    for record in layouts.LAYOUTS:
        assert record.help in schema.DATA_HELP
        assert record.expected in layouts.UNKNOWN_FORMAT
        assert record.suffixes and record.reader.count(":") == 1
        assert record.signature is not None or record.header is not None
    parser = build_parser()
    with_format = 0
    for command, sub in parser.commands.items():
        actions = {a.option_strings[0]: a for a in sub._actions if a.option_strings}
        if "--format" not in actions:
            continue
        with_format += 1
        assert tuple(actions["--format"].choices) == schema.FORMATS, command
        # A readings argument that lists layouts lists all of them: it is DATA_HELP.
        for action in sub._actions:
            text = action.help or ""
            if not action.option_strings and any(r.help in text or "ecmc" in text
                                                  for r in layouts.LAYOUTS):
                assert text == READINGS_HELP, (command, text)
    assert with_format >= 10
    for command in ("convert", "iso"):  # the readings, as every job that reads them says
        file = next(a for a in parser.commands[command]._actions if a.dest == "data")
        assert file.help == READINGS_HELP


def test_help_text_names_every_layout(capsys):
    assert main(["convert", "--help"]) == 0
    help_text = " ".join(capsys.readouterr().out.split())
    for record in layouts.LAYOUTS:
        assert record.name in help_text and record.help in help_text


def test_every_record_reads_its_own_layout(tmp_path, ess_file):
    from features.readings.rtl import write_rtl

    canonical = tmp_path / "r.csv"
    small_table().to_csv(canonical, index=False)
    rtl = write_rtl(pd.read_csv(canonical, dtype={"test_id": str}), tmp_path / "r.rtl")
    paper = tmp_path / "table2.csv"
    pd.DataFrame({"Pos. [mm]": [0, 0, 50, 50], "Dev_lin_f [mm]": [-0.002] * 4,
                  "Dev_lin_r [mm]": [0.002] * 4, "Dev_pend_f [mm]": [0.001] * 4,
                  "Dev_pend_r [mm]": [0.003] * 4, "Speed [mm/min]": [500] * 4}).to_csv(
        paper, index=False)
    camonitor = Path(__file__).parents[1] / "experiments/data/camonitor/ess_mcu1025_iso230.log"
    files = {"canonical": canonical, "paper": paper, "ecmc": ess_file, "rtl": rtl,
             "camonitor": camonitor}
    assert set(files) == set(layouts.BY_NAME)
    for name, path in files.items():
        assert layouts.detect_format(path) == name
        assert len(layouts.BY_NAME[name].read(path)) > 0


def test_unknown_layout_names_every_record(tmp_path, capsys):
    path = tmp_path / "odd.csv"
    path.write_text("time,value\n1,2\n")
    assert main(["iso", str(path)]) == 2
    line = one_error_line(capsys, "iso")
    assert "unknown format" in line and all(r.expected in line for r in layouts.LAYOUTS)


def test_records_module_stays_light():
    import subprocess
    import sys

    code = ("import sys, features.readings.schema, features.readings.layouts\n"
            "print('pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------ the workflows


def test_read_and_iso_on_the_real_ecmc_file(ess_file, psi_file, capsys):
    import backlash as bl

    readings = bl.read(ess_file)
    assert len(readings) == 50 and readings.attrs["source"] == str(ess_file)
    with pytest.warns(BacklashWarning, match=r"outlier \(kept"):
        result = bl.iso(readings)
    figures = result.figures
    assert list(figures["test_id"]) == ["ess_mcu1025_ISO230"]
    assert figures["B"].iloc[0] / 1000 == pytest.approx(0.04346, abs=6e-6)
    assert len(result.outliers) == 2 and len(result.notes) == 2
    # from a path, the same figures; and the JSON form is what `backlash iso --json` prints
    again = bl.iso(psi_file)
    assert main(["iso", str(psi_file), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(again.to_dict()))
    assert again.notes == [] and again.outliers.empty


def test_iso_drop_outliers_changes_the_figures(ess_file):
    from pipeline.workflows.iso import iso

    with pytest.warns(BacklashWarning):
        kept = iso(ess_file)
    with pytest.warns(BacklashWarning, match=r"outlier \(dropped\)"):
        dropped = iso(ess_file, drop_outliers=True)
    assert dropped.figures["R"].iloc[0] < 60 < kept.figures["R"].iloc[0]
    assert dropped.dropped and not kept.dropped


def test_iso_result_writes_its_files_and_chart(psi_file, tmp_path):
    from pipeline.workflows.iso import iso

    result = iso(psi_file)
    files = result.write(tmp_path / "out")
    assert set(files) == {"figures", "targets", "chart"}
    assert pd.read_csv(files["figures"])["A"].iloc[0] == pytest.approx(
        result.figures["A"].iloc[0])
    assert files["chart"].read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="expected a .png") as err:
        result.plot(tmp_path / "chart.pdf")
    assert err.value.parameter == "path"


def test_iso_parameters_are_checked():
    from pipeline.runner import run

    with pytest.raises(InputError, match="drop_outliers") as err:
        run("iso", small_table(), drop_outliers="yes")
    assert err.value.parameter == "drop_outliers"
    with pytest.raises(InputError) as err:
        run("iso", "x.csv", format="excel")
    assert err.value.parameter == "format"


def test_cli_prints_outlier_notes_after_the_table(ess_file, capsys):
    assert main(["iso", str(ess_file)]) == 0
    err = capsys.readouterr().err.splitlines()
    notes = [i for i, line in enumerate(err) if line.startswith("note: outlier (kept")]
    table = [i for i, line in enumerate(err) if "ess_mcu1025_ISO230" in line
             and not line.startswith("note:")]
    assert len(notes) == 2 and table and max(table) < min(notes)


def test_validate_a_hand_made_frame_and_write_it(tmp_path):
    from pipeline.workflows.convert import read, validate, write

    frame = small_table().assign(direction=lambda t: t["direction"].map({"+": "fwd",
                                                                         "-": "bwd"}))
    readings = validate(frame)
    assert set(readings["direction"]) == {"+", "-"} and readings["visit"].eq("1").all()
    assert frame["direction"].iloc[0] == "fwd"  # the caller's frame is left alone
    path = write(readings, tmp_path / "r.parquet")
    pd.testing.assert_frame_equal(read(path), readings, check_dtype=False)
    with pytest.raises(InputError, match="row 4.*column 'cycle'"):
        validate(small_table().assign(cycle=[1, 2, 3, 0.5] + [1] * 14), source="mine")
    with pytest.raises(InputError, match="not a validated readings frame") as err:
        write(frame, tmp_path / "x.csv")
    assert err.value.parameter == "readings" and not (tmp_path / "x.csv").exists()
    with pytest.raises(TypeError, match="DataFrame"):
        validate([1, 2, 3])


def test_convert_workflow(tmp_path, psi_file):
    from pipeline.workflows import workflow
    from pipeline.workflows.convert import convert

    result = convert(psi_file, tmp_path / "psi.csv")
    assert result.tests == 1 and result.out == tmp_path / "psi.csv"
    assert len(pd.read_csv(result.out)) == len(result.readings) == 50
    assert result.to_dict() == {"readings": 50, "tests": 1, "out": str(tmp_path / "psi.csv")}
    assert convert(psi_file).out is None  # nothing written without out
    assert result.write(tmp_path / "folder") == {"readings": tmp_path / "folder/readings.csv"}
    with pytest.raises(InputError, match="is the input file") as err:
        convert(tmp_path / "psi.csv", tmp_path / "." / "psi.csv")
    assert err.value.parameter == "out"
    record = workflow("convert")
    assert record.function is convert and record.inputs == ("data",)
    assert workflow("iso").summary.startswith("ISO 230-2")


# ------------------------------------------------------------------ frames made by hand


@pytest.mark.parametrize("spoil, words", [
    (lambda t: t.drop(columns="visit"), "no column 'visit'"),
    (lambda t: t.assign(deviation_um=np.where(t.index == 3, np.nan, t["deviation_um"])),
     "row 3 has deviation_um nan"),
    (lambda t: t.assign(direction="fwd"), "row 0 has direction 'fwd'"),
    (lambda t: t.assign(machine_id=7), "column 'machine_id' holds values that are not text"),
    (lambda t: t.iloc[:0], "holds no readings"),
])
@pytest.mark.parametrize("function", [iso230.per_target, iso230.axis_figures,
                                      iso230.outliers])
def test_iso_figures_refuse_an_unvalidated_frame(function, spoil, words):
    frame = spoil(small_table().assign(visit="1", repeat=1))
    with pytest.raises(InputError, match=words) as err:
        function(frame)
    assert err.value.parameter == "readings"


def test_iso_figures_of_a_plain_frame_without_optional_columns():
    # visit is part of the test key; repeat is not needed for the figures
    figures = iso230.axis_figures(small_table().assign(visit="1"))
    assert figures["B"].iloc[0] == pytest.approx(4.0)
    with pytest.raises(TypeError, match="readings must be a readings DataFrame"):
        iso230.per_target(small_table().to_dict())


def test_workflows_refuse_an_unvalidated_frame():
    import backlash as bl

    with pytest.raises(InputError, match="no column 'visit'") as err:
        bl.iso(small_table())
    assert err.value.parameter == "data"


# ------------------------------------------------------------------ bad inputs


@pytest.fixture
def loop(tmp_path):
    """A symbolic link that points at itself."""
    path = tmp_path / "loop.csv"
    os.symlink(path, path)
    return path


@pytest.mark.parametrize("argv", [
    ["convert", "{loop}", "--out", "{tmp}/out.csv"],
    ["iso", "{loop}", "--json"],
    ["iso", "{loop}", "--plot", "{tmp}/chart.png"],
])
def test_symlink_loop_as_input_is_one_line(tmp_path, loop, capsys, argv):
    argv = [a.format(loop=loop, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    line = one_error_line(capsys, argv[0])
    assert "loop.csv" in line and "symbolic link loop" in line
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "chart.png").exists()


def test_symlink_loop_from_python(loop):
    import backlash as bl

    with pytest.raises(InputError, match="cannot read file: symbolic link loop"):
        bl.read(loop)


def _both_empty(tmp_path) -> str:
    table = small_table()
    table["measured"] = table["target"] + table["deviation_um"] / 1000
    table = table.astype({"measured": object, "deviation_um": object})
    table.loc[4, ["measured", "deviation_um"]] = ""
    path = tmp_path / "holes.csv"
    table.to_csv(path, index=False)
    return str(path)


@pytest.mark.parametrize("argv", [
    ["convert", "{data}", "--out", "{tmp}/out.csv"],
    ["iso", "{data}", "--json"],
    ["train", "{data}", "--out", "{tmp}/model"],
])
def test_reading_with_both_deviation_cells_empty_is_refused(tmp_path, capsys, argv):
    argv = [a.format(data=_both_empty(tmp_path), tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    line = one_error_line(capsys, argv[0])
    assert "holes.csv" in line and "row 6" in line and "column 'deviation_um'" in line
    assert "both empty" in line
    assert capsys.readouterr().out == ""
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "model").exists()


def test_one_empty_cell_of_two_is_filled_from_the_other(tmp_path):
    from pipeline.workflows.convert import read

    table = small_table()
    table["measured"] = table["target"] + table["deviation_um"] / 1000
    table = table.astype({"deviation_um": object})
    table.loc[4, "deviation_um"] = ""
    path = tmp_path / "one.csv"
    table.to_csv(path, index=False)
    readings = read(path)
    assert readings["deviation_um"].notna().all()
    assert readings["deviation_um"].iloc[4] == pytest.approx(small_table()["deviation_um"][4])


def test_symlink_loop_as_plan_or_experiment_file_is_one_line(loop, tmp_path):
    from features.readings.fileio import read_toml
    from features.readings.plan import read_plan

    with pytest.raises(InputError, match="loop.csv: cannot read file: symbolic link loop"):
        read_plan(loop)
    toml = tmp_path / "loop.toml"
    os.symlink(toml, toml)
    with pytest.raises(InputError, match="cannot read experiment: symbolic link loop"):
        read_toml(toml, "experiment")
