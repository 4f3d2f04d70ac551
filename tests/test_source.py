"""A job's Source (``pipeline.steps.source``): ``fleet`` and ``drift`` compute on the whole
store and report the machine axes the selection keeps, so a selection never changes what is
said about an axis it keeps: its recorded compensation, its voided tests, its trace and ballbar
evidence, its forecast and the fleet's wear rate it is planned with. And the runner names no
job: what differs between jobs is declared on their records."""

from __future__ import annotations

import ast
import json
import warnings
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from store_files import cli

import backlash as bl
from features.readings.errors import InputError
from features.readings.fileio import dumps
from features.readings.selection import selection
from pipeline.steps.source import Source
from pipeline.workflows import WORKFLOWS, imported
from tests import independent_fleet
from tests.test_evidence import _ballbar, _traces

ROOT = Path(__file__).resolve().parents[1]
AS_OF = "2026-12-31"
# What describes the whole call rather than an axis: the source and its selection.
CALL_FIELDS = {"source"}


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """Two machines (M1, M2; axes X and Y; six visits) in a store with, for M1: a recorded
    compensation, trace days of X, ballbar runs of XY, and visits 1-5 of Y voided, so that Y
    has one visit left and is planned with the fleet's wear rate (the prior of every axis)."""
    folder = tmp_path_factory.mktemp("source")
    readings, _, _ = independent_fleet.fleet(visits=6)
    readings = readings[readings["machine_id"].isin(["M1", "M2"])]
    path = folder / "laser.csv"
    readings.to_csv(path, index=False)
    location = folder / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.ingest(path, store=location)
        when = pd.to_datetime(readings[(readings["machine_id"] == "M1")
                                       & (readings["axis"] == "X")]
                              .groupby("visit")["started_at"].min())
        days = [when[v] for v in sorted(when.index)]
        after = [days[-1] + pd.Timedelta(days=d) for d in (1, 2, 3)]
        bl.monitor(_traces(days + after, [4.0 + 0.1 * k for k in range(len(days) + 3)]),
                   store=location)
        bl.circle(_ballbar(days[1::2], [(3.0, 4.0)] * len(days[1::2])), store=location)
        bl.compensate(str(location), machine="M1", axis="X", controller="csv",
                      store=str(location), track=False)
        for visit in ("1", "2", "3", "4", "5"):
            bl.void(location, machine="M1", axis="Y", visit=visit, reason="setup error")
    return location


def _plain(result) -> dict:
    return json.loads(dumps(result.to_dict()))


def _quiet(job: str, *args, **params) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _plain(getattr(bl, job)(*args, track=False, **params))


def fleet_axes(j: dict) -> dict:
    return {(a["machine_id"], a["axis"]): {k: v for k, v in a.items() if k not in CALL_FIELDS}
            for a in j["axes"]}


def drift_axes(j: dict) -> dict:
    return {(s["machine_id"], s["axis"]): s for s in j["series"]}


@pytest.fixture(scope="module")
def whole(store) -> dict:
    """``fleet`` and ``drift --evidence all`` of the whole store, per machine axis."""
    return {"fleet": fleet_axes(_quiet("fleet", str(store), as_of=AS_OF)),
            "drift": drift_axes(_quiet("drift", str(store), as_of=AS_OF, evidence="all"))}


def test_the_store_holds_what_the_selection_must_keep(whole):
    """The fixture is what the tests need: M1's compensation, voids, evidence and a fleet
    rate drawn from other axes (so a selection of M1 would change it if it were computed on
    the selection)."""
    x, y = whole["fleet"][("M1", "X")], whole["fleet"][("M1", "Y")]
    assert x["last_compensation"] is not None
    assert len(y["voided_tests"]) > 0 and y["visits"] == 1
    assert y["fleet_wear_rate_per_month"] is not None
    assert len(x["evidence"]["trace"]) > 0 and len(x["evidence"]["ballbar"]) > 0
    assert x["offsets_um"]["trace"] is not None
    assert set(whole["fleet"]) == {("M1", "X"), ("M1", "Y"), ("M2", "X"), ("M2", "Y")}


def _cli_json(capsys, argv: list) -> dict:
    """The JSON ``backlash ARGV --json --no-track`` prints (exit 3, an alert, is no failure)."""
    code, out, err = cli(capsys, [*argv, "--json", "--no-track"])
    assert code in (0, 3), err
    return json.loads(out)


def test_fleet_of_a_machine_says_what_the_whole_fleet_says_of_it(store, whole, capsys):
    """``bl.fleet(store, machine="M1")`` and ``backlash fleet STORE --machine M1 --json``: M1's
    axes exactly as in the whole store's view (compensation, voids, evidence, fleet rate)."""
    expected = {k: v for k, v in whole["fleet"].items() if k[0] == "M1"}
    python = fleet_axes(_quiet("fleet", str(store), as_of=AS_OF, machine="M1"))
    assert python == expected
    command = fleet_axes(_cli_json(capsys, ["fleet", store, "--machine", "M1", "--as-of",
                                            AS_OF]))
    assert command == expected


def test_fleet_of_one_axis_says_what_the_whole_fleet_says_of_it(store, whole, capsys):
    """The axis filter too: M1 Y alone keeps its voids and the fleet's wear rate."""
    command = fleet_axes(_cli_json(capsys, ["fleet", store, "--machine", "M1", "--axis", "Y",
                                            "--as-of", AS_OF]))
    assert command == {("M1", "Y"): whole["fleet"][("M1", "Y")]}


def test_drift_of_a_machine_says_what_the_whole_store_says_of_it(store, whole, capsys):
    """``drift --evidence all --machine M1``: M1's series (with its trace and ballbar points
    and their offsets) as in the whole store's drift."""
    expected = {k: v for k, v in whole["drift"].items() if k[0] == "M1"}
    assert "trace" in expected[("M1", "X")]["source"]
    python = drift_axes(_quiet("drift", str(store), as_of=AS_OF, evidence="all",
                               machine="M1"))
    assert python == expected
    command = drift_axes(_cli_json(capsys, ["drift", store, "--machine", "M1", "--evidence",
                                            "all", "--as-of", AS_OF]))
    assert command == expected


def test_drift_reads_a_stores_trace_days_with_a_selection(store, capsys):
    """``drift STORE --evidence trace --machine M1`` works (it used to ask for the store as
    data, the runner having replaced it by a frame)."""
    j = _cli_json(capsys, ["drift", store, "--evidence", "trace", "--machine", "M1",
                           "--as-of", AS_OF])
    x = drift_axes(j)[("M1", "X")]
    assert j["evidence"] == "laser,trace" and x["source"].count("trace") > 0
    assert x["offsets_um"]["trace"] is not None
    assert {k[0] for k in drift_axes(j)} == {"M1"}


def test_a_selection_that_keeps_nothing_is_still_refused(store):
    with pytest.raises(InputError, match="no test matches machine M9"):
        bl.fleet(str(store), machine="M9", track=False)
    with pytest.raises(InputError, match="no test matches machine M9"):
        bl.drift(str(store), machine="M9", track=False)


@settings(max_examples=6, deadline=None)
@given(machines=st.one_of(st.none(), st.permutations(["M1", "M2"]),
                          st.lists(st.sampled_from(["M1", "M2"]), min_size=1, unique=True)),
       axes=st.one_of(st.none(), st.permutations(["X", "Y"]), st.sampled_from([["X"], ["Y"]])))
def test_the_order_and_grouping_of_a_selection_changes_nothing(store, whole, machines, axes):
    """Selecting [M1, M2] or [M2, M1] or one machine, any axes, gives each kept axis the JSON
    it has without a selection."""
    got = fleet_axes(_quiet("fleet", str(store), as_of=AS_OF, machine=machines, axis=axes))
    kept = {k: v for k, v in whole["fleet"].items()
            if (machines is None or k[0] in machines) and (axes is None or k[1] in axes)}
    assert got == kept


# --------------------------------------------------------------------------- the Source
def test_a_source_reads_the_selection_or_every_axis_and_knows_its_store(store, tmp_path):
    source = Source(str(store), selection=selection(machine="M1", axis="X"))
    assert source.is_store and source.store == str(store)
    assert source.keeps("M1", "X") and not source.keeps("M1", "Y") and not source.keeps("M2", "X")
    picked = source.readings()
    assert set(map(tuple, picked[["machine_id", "axis"]].drop_duplicates().to_numpy())) == {
        ("M1", "X")}
    every = source.all_readings()
    assert set(every["machine_id"]) == {"M1", "M2"} and set(every["axis"]) == {"X", "Y"}
    assert source.kept(every).shape == picked.shape
    path = tmp_path / "some.csv"
    bl.write(picked, path)
    assert not Source(str(path)).is_store and Source(str(path)).store is None
    frame = Source(picked)
    assert frame.store is None and frame.all_readings() is not None
    assert Source.of(source) is source


def test_fleet_and_drift_read_each_record_once_through_their_source(store, whole,
                                                                      monkeypatch):
    """No second store reader: the store's records are read through the Source, each kind
    once (the fleet's probing limits, forecasts, compensations, voids, trace and ballbar
    evidence alike), and each axis's offsets to the laser are found once; the results stay
    those of the store."""
    from pipeline.steps import evidence
    from pipeline.store import records

    reads, offsets = [], []
    read_records, axis_offsets = records.read_records, evidence.axis_offsets
    monkeypatch.setattr(records, "read_records",
                        lambda s, kind: reads.append(kind) or read_records(s, kind))
    monkeypatch.setattr(evidence, "axis_offsets",
                        lambda v, e: offsets.append(1) or axis_offsets(v, e))
    assert fleet_axes(_quiet("fleet", str(store), as_of=AS_OF)) == whole["fleet"]
    assert sorted(reads) == sorted(set(reads)) and "probing" in reads and "trace" in reads
    assert len(offsets) == len(whole["fleet"])
    reads.clear()
    offsets.clear()
    assert drift_axes(_quiet("drift", str(store), as_of=AS_OF, evidence="all")) == whole[
        "drift"]
    assert sorted(reads) == ["ballbar", "trace"] and len(offsets) == len(whole["fleet"])


def test_a_source_reads_a_given_store_s_records_or_none(store, tmp_path):
    source = Source(str(store))
    assert source.records_store() == str(store) and source.records_store(tmp_path) is None
    found = source.records(("compensation", "voided"))
    assert set(found) == {"compensation", "voided"} and ("M1", "X") in found["compensation"]
    assert source.records(("compensation",))["compensation"] is found["compensation"]
    path = tmp_path / "some.csv"
    bl.write(source.readings(), path)
    assert Source(str(path)).records() == {} and Source(str(path)).live() == []
    assert Source(str(path)).records(store=str(store))["voided"] == found["voided"]


def test_the_dates_of_a_selection_still_choose_the_tests_of_every_axis(store):
    """``since``/``until`` select tests (the fleet is computed within them), machine and axis
    select the axes reported."""
    source = Source(str(store), selection=selection(machine="M1", until="2025-06-30"))
    every = source.all_readings()
    assert set(every["machine_id"]) == {"M1", "M2"}
    assert (pd.to_datetime(every["started_at"], utc=True)
            <= pd.Timestamp("2025-07-01", tz="UTC")).all()


def test_importing_the_source_imports_no_numeric_library():
    import subprocess
    import sys

    code = ("import sys; import pipeline.steps.source; "
            "print(sorted(m for m in ('pandas', 'numpy', 'pyarrow') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "[]"


# --------------------------------------------------------------------------- the records
def _code_names(path: Path) -> set[str]:
    """The names in the runner's code: string constants (and the parts of a dotted one),
    variables, attributes and imported modules; docstrings and messages' words left out
    (a "fleet store" is no job)."""
    tree = ast.parse(path.read_text())
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docstrings:
            found.add(node.value)  # a job's name as a key or a comparison's value
            if " " not in node.value:  # a dotted path: the modules it names
                found |= set(node.value.split("."))
        elif isinstance(node, ast.Name):
            found.add(node.id)
        elif isinstance(node, ast.Attribute):
            found.add(node.attr)
        elif isinstance(node, ast.alias):
            found |= set(node.name.split("."))
        elif isinstance(node, ast.ImportFrom) and node.module:
            found |= set(node.module.split("."))
    return found


def test_the_runner_names_no_job():
    """What differs between jobs is on their records; the runner's code names none of them
    (``store`` is also the runner's own parameter, the fleet store a result is recorded in)."""
    import inspect

    from pipeline import runner

    own = set(inspect.signature(runner.run).parameters)
    named = _code_names(ROOT / "pipeline" / "runner.py")
    jobs = {w.name for w in WORKFLOWS} | {w.name.replace("-", "_") for w in WORKFLOWS}
    assert sorted((jobs - own) & named) == []
    comments = [line for line in (ROOT / "pipeline" / "runner.py").read_text().splitlines()
                if "#" in line]
    assert not [c for c in comments for job in jobs - own if f"({job}" in c or f"{job}'s" in c]


def test_the_records_declare_plain_data_that_resolves():
    """Recorders and model logging are dotted names (the records stay plain data) naming
    functions; the reader options are those of the job's table (``RAW_LOG``)."""
    from pipeline.steps.parameters import RAW_LOG

    for record in WORKFLOWS:
        for dotted in (record.records, record.model_logging):
            assert dotted is None or callable(imported(dotted)), (record.name, dotted)
        table = record.parameters  # a raw log's reader's own options, not a trace log's
        assert set(record.reader_options) == {k for k in RAW_LOG
                                              if table.get(k) is RAW_LOG[k]}, record.name
    assert {w.name for w in WORKFLOWS if w.records} >= {"compensate", "kinematics"}
    assert {w.name for w in WORKFLOWS if w.source} >= {"fleet", "drift"}
