"""Configuration files as typed data: one reader from TOML into dataclasses for twin campaigns,
experiment files and discovery scenarios; presets are TOML files; meaningless values are refused
in one line naming the file and the key."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from features.readings.config import as_table, read_config
from features.readings.errors import InputError
from pipeline.cli import main


@dataclass
class Inner:
    rate: float = 1.0
    names: list[str] = field(default_factory=lambda: ["a"])


@dataclass
class Outer:
    count: int = 2
    kind: Literal["x", "y"] = "x"
    flag: bool = False
    limits: list[float] | None = None
    inner: Inner = field(default_factory=Inner)
    tables: dict[str, dict[str, float]] = field(default_factory=dict)
    items: list[Inner] = field(default_factory=list)


def test_a_toml_file_becomes_the_dataclass(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('count = 3.0\nkind = "y"\n[inner]\nrate = 2\n[tables.t]\nk = 1.5\n'
                    '[[items]]\nnames = ["b", "c"]\n')
    config = read_config(path, Outer)
    assert config == Outer(count=3, kind="y", inner=Inner(rate=2), tables={"t": {"k": 1.5}},
                           items=[Inner(names=["b", "c"])])
    assert isinstance(config.count, int)
    assert list(as_table(config)) == ["count", "kind", "flag", "limits", "inner", "tables",
                                      "items"]


def test_a_base_fills_what_the_source_leaves_out():
    base = Outer(count=5, inner=Inner(rate=3.0, names=["z"]), tables={"old": {}})
    config = read_config({"inner": {"rate": 4.0}, "tables": {"new": {}}}, Outer, base=base)
    assert config.count == 5 and config.inner == Inner(rate=4.0, names=["z"])
    assert config.tables == {"new": {}}  # a free table is replaced whole
    assert base.inner.rate == 3.0


@pytest.mark.parametrize("table, key, words", [
    ({"cont": 1}, "cont", "unknown key 'cont'; expected count, kind"),
    ({"inner": {"rat": 1}}, "inner.rat", "unknown key 'inner.rat'"),
    ({"count": 1.5}, "count", "expected a whole number, got 1.5"),
    ({"count": "2"}, "count", "expected a number"),
    ({"count": True}, "count", "expected a number"),
    ({"kind": "z"}, "kind", "expected one of x, y, got 'z'"),
    ({"kind": ["x"]}, "kind", "expected text"),
    ({"flag": 1}, "flag", "expected true or false"),
    ({"limits": [1.0, float("nan")]}, "limits", "expected a list of numbers (finite)"),
    ({"inner": 3}, "inner", "expected a table, got 3"),
    ({"inner": {"names": "a"}}, "inner.names", "expected a list of text"),
    ({"tables": {"t": {"k": "big"}}}, "tables.t.k", "expected a number (finite)"),
    ({"tables": {"t": 1.0}}, "tables.t", "expected a table"),
    ({"items": [{"rate": "fast"}]}, "items[1].rate", "expected a number"),
    ({"items": [1]}, "items[1]", "expected a table"),
])
def test_wrong_keys_and_kinds_name_the_file_and_the_key(table, key, words):
    with pytest.raises(InputError) as caught:
        read_config(table, Outer, file="c.toml")
    err = caught.value
    assert err.column == key and err.file == "c.toml" and words in err.message, err.line()
    assert len(err.line().splitlines()) == 1


# --------------------------------------------------------------------------- twin campaigns
@pytest.mark.parametrize("text, column, words", [
    ("[fleet]\ninterval_days = -30\n", "fleet.interval_days", "a duration >= 0 days, got -30"),
    ("[fleet]\nhours_per_day = 30.0\n", "fleet.hours_per_day", "0-24 h a day"),
    ("[fleet]\nhours_per_day = -1.0\n", "fleet.hours_per_day", "0-24 h a day"),
    ("[fleet]\nmachines = -2\n", "fleet.machines", "must be at least 1, got -2"),
    ("[fleet]\nvisits = 0\n", "fleet.visits", "must be at least 1, got 0"),
    ("[plan]\nrepeats = -1\n", "plan.repeats", "must be at least 1"),
    ("[plan]\nn_targets = -4\n", "plan.n_targets", "must be at least 1"),
    ("[plan]\noverrun_mm = -5.0\n", "plan.overrun_mm", "a distance >= 0 mm"),
    ("[plan]\nstart_mm = 300.0\nstop_mm = 100.0\n", "plan.stop_mm", "must be above start_mm"),
    ("[fleet]\nadjust_at = [0]\n", "fleet.adjust_at", "visits count from 1"),
    ("[fleet]\nfailure_at = -1\n", "fleet.failure_at", "visits count from 1"),
    ("[fleet]\nfailure_jump_um = -3.0\n", "fleet.failure_jump_um", "adds lost motion"),
    ("[environment]\nambient_spread_k = -0.3\n", "environment.ambient_spread_k",
     "a standard deviation >= 0"),
    ("[effects.backlash]\nb0 = 1.0\n", "effects.backlash", "unknown parameter 'b0' of backlash"),
])
def test_meaningless_campaign_values_are_refused_in_one_line(tmp_path, capsys, text, column,
                                                             words):
    path = tmp_path / "campaign.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["simulate", "--config", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert words in err[0] and f"column {column!r}" in err[0] and "campaign.toml" in err[0], err
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


def test_every_preset_is_a_toml_campaign_file():
    from models.physics import PRESETS
    from models.physics.campaign import Campaign, load_config

    assert {"paper", "fleet", "drift", "demo", "indirect", "wear", "compensation",
            "rotary"} <= set(PRESETS)
    for name, path in PRESETS.items():
        assert path.suffix == ".toml" and path.parent.name == "presets"
        assert isinstance(load_config(name), Campaign)
    assert load_config("paper") == Campaign()  # the paper plan is the defaults
    drift = load_config("drift")
    assert (drift.system, drift.fleet.visits, drift.fleet.failure_at) == ("indirect", 20, 15)
    # a config file applies on top of a preset; its [effects] replaces the preset's whole
    both = load_config({"fleet": {"visits": 2}, "effects": {"backlash": {}}}, preset="drift")
    assert both.fleet.visits == 2 and both.fleet.machines == 3 and both.effects == {
        "backlash": {}}


def test_a_bad_preset_file_names_itself(tmp_path, monkeypatch):
    from models import physics
    from models.physics import campaign

    bad = tmp_path / "broken.toml"
    bad.write_text("[fleet]\nvisits = 'many'\n")
    monkeypatch.setitem(physics.PRESETS, "broken", bad)
    with pytest.raises(InputError) as caught:
        campaign.load_config("broken")
    assert caught.value.file == str(bad) and caught.value.column == "fleet.visits"


def test_memory_comes_from_psutil(monkeypatch):
    import psutil

    from models.physics import campaign

    assert campaign.available_memory_bytes() == pytest.approx(
        psutil.virtual_memory().available, rel=0.5)

    class Small:
        available = 1e6

    monkeypatch.setattr(psutil, "virtual_memory", lambda: Small())
    with pytest.raises(InputError, match="memory available") as caught:
        campaign.load_config({"fleet": {"machines": 2}})
    assert caught.value.column == "fleet"


# --------------------------------------------------------------------------- the workflow
def test_simulate_workflow_returns_frames_and_writes_them(tmp_path):
    from pipeline.workflows import workflow

    record = workflow("simulate")
    result = record.function(preset="demo", config={"fleet": {"visits": 2}}, seed=3)
    assert result.readings["visit"].nunique() == 2 and len(result.truth) and len(result.visits)
    assert result.parameters["seed"] == 3 and result.config.fleet.visits == 2
    files = result.write(tmp_path / "twin")
    assert sorted(p.name for p in files.values()) == ["parameters.json", "readings.csv",
                                                      "truth.csv", "truth_visits.csv"]
    assert result.to_dict()["readings"] == len(result.readings)
    assert record.inputs == ("config",)


@pytest.mark.parametrize("kwargs, parameter, words", [
    ({"seed": -1}, "seed", "must be an int in the range"),
    ({"seed": True}, "seed", r"must be an int in the range \[0, 4294967295\]; got True"),
    ({"session_seed": 1.5}, "session_seed", "must be an int"),
    ({"preset": "nope"}, "preset", "unknown preset 'nope'"),
    ({"config": 3}, "config", "must be an instance of"),
])
def test_simulate_workflow_names_the_parameter(kwargs, parameter, words):
    import backlash as bl  # the runner checks a call against the job's table

    with pytest.raises(InputError, match=words) as caught:
        bl.simulate(**kwargs)
    assert caught.value.parameter == parameter


def test_command_help_is_the_workflow_summary():
    from pipeline.cli import build_parser
    from pipeline.workflows import workflow

    command = build_parser(["simulate"]).commands["simulate"]
    assert command.description == workflow("simulate").summary


# --------------------------------------------------------------------------- scenarios
@pytest.mark.parametrize("text, column, words", [
    ("[designs.A]\nplan = { feeds = [1.0] }\n", "designs.A.plan.feeds", "unknown key"),
    ("[designs.A]\nhidden = ['gremlin']\n", "designs.A.hidden", "unknown effect 'gremlin'"),
    ("[designs.A]\nnoise_um = 'loud'\n", "designs.A.noise_um", "expected a number"),
    ("[designs.A]\n[[special]]\nname = 'x'\ndesign = 'B'\n", "special[1].design",
     "unknown design 'B'"),
    ("[designs.A]\n[[special]]\nname = 'x'\ndesign = 'A'\nkind = 'odd'\n", "special[1].kind",
     "expected one of hidden, null, confounded, aliased"),
    ("[designs.A]\n[[special]]\ndesign = 'A'\n", "special[1].name", "missing key"),
    ("baselines = ['backlash']\n[designs.A]\n", "baselines", "unknown key"),
])
def test_bad_scenario_files_name_the_file_and_the_key(tmp_path, text, column, words):
    from models.discovery.benchmark import read_scenarios

    path = tmp_path / "scenarios.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as caught:
        read_scenarios(path)
    assert caught.value.column == column and caught.value.file == str(path)


def test_shipped_scenarios_read_into_dataclasses():
    from pathlib import Path

    from models.discovery import benchmark as bench

    path = Path(__file__).resolve().parents[1] / "experiments" / "hidden_effect_scenarios.toml"
    spec = bench.read_scenarios(path)
    assert isinstance(spec, bench.Scenarios) and set(spec.designs) >= {"A", "N"}
    assert spec.designs["N"].hidden == [] and spec.designs["A"].hidden == "all"
    scenarios = bench.expand(spec, seeds=[1])
    assert {s["kind"] for s in scenarios} == {"hidden", "null", "confounded", "aliased"}
    assert bench.expand(str(path), seeds=[1]) == scenarios
