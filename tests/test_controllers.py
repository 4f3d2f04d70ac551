"""One record per controller: the records, the twin's readers, the CLI and the docs agree."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from features.readings.errors import InputError
from models.physics import controller as model
from pipeline.compensation import CONTROLLERS, controllers_table, resolve
from pipeline.compensation.common import Options
from pipeline.compensation.profile import AxisProfile

DOCS = Path(__file__).resolve().parents[1] / "docs" / "controllers.md"


def profile(axis: str = "X") -> AxisProfile:
    x = np.array([0.0, 50.0, 100.0, 150.0, 200.0])
    e = 0.01 * x
    u = np.full_like(x, 0.2)
    return AxisProfile("M1", axis, x, e - 2.0, e + 2.0, u, u, "measured", [])


def test_records_and_the_twins_readers_name_the_same_controllers():
    assert list(CONTROLLERS) == list(model.READERS)
    for name, record in CONTROLLERS.items():
        assert record.name == name and record.kind in ("table", "scalar")
        assert set(record.axes) <= {"linear", "rotary"} and record.axes


def test_names_and_aliases_are_unambiguous_and_resolve():
    spelled = [n for c in CONTROLLERS.values() for n in (c.name, *c.aliases)]
    assert len(spelled) == len(set(spelled)) and "all" not in spelled
    for record in CONTROLLERS.values():
        for alias in (record.name, *record.aliases):
            assert resolve(alias.upper()) == [record.name]
    assert resolve("all") == list(CONTROLLERS)
    assert resolve(["sinumerik", "siemens", "csv"]) == ["siemens", "csv"]


def test_the_cli_offers_the_records():
    from pipeline.cli import build_parser
    from pipeline.workflows.compensate import controller_help

    command = build_parser().commands["compensate"]
    option = next(a for a in command._actions if a.dest == "controller")
    assert option.help == controller_help()
    offered = re.match(r"one or more of (.*) \(comma-separated\)", option.help)[1].split(", ")
    assert offered == list(CONTROLLERS)
    for record in CONTROLLERS.values():
        assert all(f"{a}={record.name}" in option.help for a in record.aliases)


def test_the_docs_table_is_the_records():
    """The page holds the marker the site's build fills in with this table (docs/hooks.py)."""
    table = controllers_table()
    assert "\n<!-- table: controllers -->\n" in DOCS.read_text(encoding="utf-8")
    rows = table.splitlines()[2:]
    assert [re.match(r"\| `(\w+)`", row)[1] for row in rows] == list(CONTROLLERS)


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_each_record_reads_back_what_it_writes(name, tmp_path):
    record = CONTROLLERS[name]
    p = profile()
    written = record.writer(p, tmp_path, Options())
    comp = record.reader(written["files"])
    assert isinstance(comp, model.Compensation)
    reversal = 1000 * (comp.offset_mm(p.target, 1) - comp.offset_mm(p.target, -1))
    assert np.allclose(reversal, -p.reversal, atol=0.6)  # takes up the 4 um lost motion


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_axis_kinds_are_what_the_writer_accepts(name, tmp_path):
    record = CONTROLLERS[name]
    if "rotary" in record.axes:
        assert record.writer(profile("A"), tmp_path, Options())["files"]
    else:
        with pytest.raises(InputError, match="X, Y and Z only") as err:
            record.writer(profile("A"), tmp_path, Options())
        assert err.value.parameter == "controller"


def test_unknown_controller_names_the_parameter_and_the_records():
    for given in ("okuma", ["linuxcnc", "okuma"], ",", []):
        with pytest.raises(InputError, match="unknown controller") as err:
            resolve(given)
        assert err.value.parameter == "controller"
        assert ", ".join(CONTROLLERS) in err.value.message
    with pytest.raises(InputError, match="unknown controller 'okuma'") as err:
        model.load("okuma", {})
    assert err.value.parameter == "controller"


def test_the_names_users_type_for_their_controllers():
    assert resolve("840D,828d,TNC640,0i,tnc7,840dsl") == ["siemens", "heidenhain", "fanuc"]
    assert resolve("SINUMERIK, 840D-sl, Fanuc, 0i-F, 31i-B, heidenhain, lcnc, emc2") == [
        "siemens", "fanuc", "heidenhain", "linuxcnc"]


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_each_written_file_is_recognised_as_its_controllers_own(name, tmp_path):
    """``--active`` tells a file's controller and role from its text: each file written is
    recognised as its own role, and as no other controller's (Marlin and RepRapFirmware share
    ``M425``, and one reader)."""
    files = CONTROLLERS[name].writer(profile(), tmp_path, Options())["files"]
    for role, path in files.items():
        text = path.read_text()
        found = {n: r for n, record in CONTROLLERS.items() for r, pattern in record.recognise
                 if re.search(pattern, text, re.MULTILINE)}
        assert found[name] == role
        assert set(found) == ({"marlin", "reprap"} if name in ("marlin", "reprap") else {name})
