"""backlash stiffness --store: each visit's stiffness per centre and axis and the map's form,
recorded alike from the command line and from Python, checked, read back as the job found it,
once only; a refused run records nothing."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from pipeline.cli import main
from pipeline.store.records import check_stiffness, read_records
from tests import independent_ldbb as gen

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")
TWIN = "experiments/data/twin/readings.csv"


@pytest.fixture(scope="module")
def ldbb(tmp_path_factory):
    """Two visits of the independent generator's machine, dated: its first nine centres."""
    path = tmp_path_factory.mktemp("ldbb") / "ldbb.csv"
    table = gen.ldbb_table(seed=0, centres=gen.grid_centres()[:9], readings=72)
    second = table.assign(visit="2", test_id=table["test_id"] + "-v2",
                          started_at="2026-09-01T08:00:00Z")
    both = pd.concat([table.assign(visit="1", started_at="2026-05-04T08:00:00Z"), second],
                         ignore_index=True)
    both.to_csv(path, index=False)
    return str(path)


def new_store(tmp_path, name: str) -> str:
    location = str(tmp_path / name)
    bl.ingest(TWIN, location, track=False)
    return location


def without_time(records: dict) -> dict:
    return {k: [{n: v for n, v in r.items() if n != "recorded_at"} for r in rs]
            for k, rs in records.items()}


def test_cli_and_python_record_the_same_stiffness_once(ldbb, tmp_path, capsys):
    python_store, cli_store = new_store(tmp_path, "py"), new_store(tmp_path, "cli")
    result = bl.stiffness(ldbb, ram_top_mm=gen.RAM_TOP_MM, store=python_store, track=False)
    assert (result.recorded.added, result.recorded.unchanged) == (4, 0)  # 2 visits x X, Y
    capsys.readouterr()
    argv = ["stiffness", ldbb, "--ram-top", str(gen.RAM_TOP_MM), "--store", cli_store,
            "--no-track"]
    assert main(argv) == 0
    assert f"4 stiffness records recorded in {cli_store}" in capsys.readouterr().err
    assert main(argv) == 0  # the same run again adds nothing
    assert "0 stiffness records recorded" in capsys.readouterr().err
    recorded = read_records(python_store, "stiffness")
    assert without_time(recorded) == without_time(read_records(cli_store, "stiffness"))
    assert sorted(recorded) == [("VMC-7", "X"), ("VMC-7", "Y")]
    # what was recorded is what the job found, per visit, dated by its started_at
    [machine] = result.machines
    for axis in "XY":
        by_visit = {r["visit"]: r for r in recorded[("VMC-7", axis)]}
        assert {v: r["date"] for v, r in by_visit.items()} == {"1": "2026-05-04",
                                                               "2": "2026-09-01"}
        for visit, r in by_visit.items():
            found = [c for c in machine["centres"] if c["visit"] == visit]
            assert [c["centre_mm"] for c in r["centres"]] == [c["centre_mm"] for c in found]
            assert [c["stiffness_n_per_um"] for c in r["centres"]] == [
                c["stiffness_n_per_um"][axis] for c in found]
            assert [c["stiffness_u_n_per_um"] for c in r["centres"]] == [
                c["stiffness_u_n_per_um"][axis] for c in found]
            assert r["map"] == {"form": machine["map"]["form"],
                                "decided": machine["map"]["decided"],
                                "ram_top_mm": gen.RAM_TOP_MM}
            truth = gen.true_stiffness(np.array([c["centre_mm"] for c in r["centres"]]))
            k = np.array([c["stiffness_n_per_um"] for c in r["centres"]])
            assert np.abs(k / truth[:, "XY".index(axis)] - 1).max() < 0.05
    assert main(["store", "check", cli_store]) == 0, capsys.readouterr().err


def test_a_refused_run_records_nothing(ldbb, tmp_path, capsys):
    location = new_store(tmp_path, "fleet")
    bad = tmp_path / "one_load.csv"
    pd.read_csv(ldbb).assign(load_n=300.0).to_csv(bad, index=False)
    capsys.readouterr()
    assert main(["stiffness", str(bad), "--store", location, "--no-track"]) == 2
    err = capsys.readouterr().err.strip()
    assert "every run has load_n 300 N" in err and "\n" not in err, err
    assert main(["stiffness", ldbb, "--store", str(tmp_path / "nowhere"), "--no-track"]) == 2
    assert "holds no store yet" in capsys.readouterr().err
    assert read_records(location, "stiffness") == {}
    assert not (tmp_path / "nowhere").exists()


def test_a_stiffness_record_that_cannot_be_interpreted_is_refused(ldbb):
    from features.readings.errors import InputError
    from pipeline.store.records import stiffness_records

    good = stiffness_records(bl.stiffness(ldbb, track=False))[0]
    assert check_stiffness(good) is good
    for change, words in (({"axis": "C"}, "axis C is not linear"),
                          ({"centres": []}, "centres must list"),
                          ({"map": {"form": "cubic"}}, "map must hold"),
                          ({"extra": 1}, "unknown field(s) extra")):
        with pytest.raises(InputError, match=words.replace("(", r"\(").replace(")", r"\)")):
            check_stiffness({**good, **change})
