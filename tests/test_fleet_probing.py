"""The fleet view trends a rotary axis's play from its probing visits (``backlash kinematics
--store``): three probing visits of a machine whose A axis play grows 6, 10, 14 arcsec (the
independent generator, tests/independent_probing.py) while its C axis stays at 5 arcsec; C
also has laser visits (tests/independent_fleet.py), A none. The series, the slope, the crossing
of --threshold-arcsec and of --limits, alike from the command line and from Python, and on the
site's index."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from independent_fleet import fleet as independent

import backlash as bl
from pipeline.cli import main
from tests import independent_probing as ip

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")
MACHINE = "M1"
DAYS = ("2026-01-10", "2026-03-10", "2026-05-10")
PLAY_A = (6.0, 10.0, 14.0)  # arcsec, the truth put in
PLAY_C = 5.0
AS_OF = "2026-06-30"
MONTH = 30.4375  # days


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    root = tmp_path_factory.mktemp("probing")
    laser = independent(0, visits=6, rotary=True)[0]
    laser = laser[(laser["machine_id"] == MACHINE) & (laser["axis"] == "C")]
    laser.to_csv(root / "laser.csv", index=False)
    location = str(root / "fleet")
    bl.ingest(str(root / "laser.csv"), location, track=False)
    machine = {**ip.machine(0, 46.0), "machine_id": MACHINE}
    for k, (day, play) in enumerate(zip(DAYS, PLAY_A)):
        probes = ip.probing({**machine, "play_arcsec": {"A": play, "C": PLAY_C}}, seed=k,
                            started_at=f"{day}T08:00:00Z").assign(visit=str(k + 1))
        probes.to_csv(root / f"probes{k}.csv", index=False)
        bl.kinematics(str(root / f"probes{k}.csv"), store=location, track=False)
    return location


def by_axis(found: dict) -> dict:
    return {(p["machine_id"], p["axis"]): p for p in found["probing"]}


def true_crossing(limit: float) -> pd.Timestamp:
    """Where the line through the plays put in reaches ``limit``."""
    t = [(pd.Timestamp(d) - pd.Timestamp(DAYS[0])).days for d in DAYS]
    slope = (PLAY_A[-1] - PLAY_A[0]) / (t[-1] - t[0])  # per day, the plays lie on a line
    return pd.Timestamp(DAYS[0]) + pd.Timedelta(days=(limit - PLAY_A[0]) / slope)


def test_the_fleet_trends_the_play_and_its_crossing(store):
    view = bl.fleet(store, threshold_arcsec=20.0, as_of=AS_OF, track=False)
    found = by_axis(view.to_dict())
    a, c = found[(MACHINE, "A")], found[(MACHINE, "C")]
    assert (a["laser_visits"], c["laser_visits"]) == (False, True)
    assert [v.axis for v in view.axes] == ["C"]  # the laser series stays as it was
    assert a["unit"] == "arcsec" and a["history"]["dates"] == list(DAYS)
    for found_play, true in zip(a["history"]["play_arcsec"], PLAY_A):
        assert abs(found_play - true) < 1
    assert all(abs(p - PLAY_C) < 1 for p in c["history"]["play_arcsec"])
    true_slope = (PLAY_A[-1] - PLAY_A[0]) / ((pd.Timestamp(DAYS[-1])
                                              - pd.Timestamp(DAYS[0])).days / MONTH)
    assert abs(a["slope_arcsec_per_month"] / true_slope - 1) < 0.05
    assert abs(c["slope_arcsec_per_month"]) < 0.1
    assert a["threshold_arcsec"] == 20.0
    crossing = pd.Timestamp(a["crossing_date"])
    assert abs((crossing - true_crossing(20.0)).days) <= 15
    assert a["alerts"] == ["crossing_soon"] and c["alerts"] == [] and c["crossing_date"] is None
    assert {"kind": "crossing_soon", "machine_id": MACHINE, "axis": "A", "source": "probing"
            }.items() <= next(x for x in view.alerts if x.get("source") == "probing").items()
    assert a["last_errors"]["delta_x_A_um"] is None  # inseparable, as the probing said


def test_limits_per_axis_move_the_crossing(store):
    view = bl.fleet(store, limits={MACHINE: {"A_arcsec": 30.0}}, as_of=AS_OF, track=False)
    assert not any("applies to nothing" in n for n in view.notes), view.notes  # A is probed
    a = by_axis(view.to_dict())[(MACHINE, "A")]
    assert a["threshold_arcsec"] == 30.0
    assert abs((pd.Timestamp(a["crossing_date"]) - true_crossing(30.0)).days) <= 20
    assert a["alerts"] == []  # a crossing more than six months after the last visit


def test_cli_prints_what_python_gives_and_the_site_lists_it(store, tmp_path, capsys):
    site = tmp_path / "site"
    capsys.readouterr()
    code = main(["fleet", store, "--threshold-arcsec", "20", "--as-of", AS_OF, "--json",
                 "--out", str(site), "--no-track"])
    assert code == 3  # the probing play's crossing_soon is an alert
    printed = json.loads(capsys.readouterr().out)
    python = bl.fleet(store, threshold_arcsec=20.0, as_of=AS_OF, track=False).to_dict()
    assert printed["probing"] == json.loads(json.dumps(python["probing"]))
    assert json.loads((site / "fleet.json").read_text())["probing"] == printed["probing"]
    index = (site / "index.html").read_text()
    assert "Rotary axes: play from probing" in index
    row = index[index.index("Rotary axes: play from probing"):]
    assert f"{MACHINE} A</td><td>no</td>" in row and f"{MACHINE} C</td><td>yes</td>" in row
    assert "crossing_soon" in row and a_slope(printed) in row


def a_slope(found: dict) -> str:
    return format(by_axis(found)[(MACHINE, "A")]["slope_arcsec_per_month"], "+.3f")


def test_a_visit_without_a_date_is_left_out_with_a_note():
    from pipeline.steps.rotary_evidence import probing_frame

    record = {"machine_id": MACHINE, "axis": "A", "visit": "1", "date": None,
              "play_arcsec": 6.0, "play_u_arcsec": 0.1}
    frame, kept, notes = probing_frame([record, {**record, "visit": "2",
                                                 "date": "2026-03-10"}])
    assert frame["visit"].tolist() == ["2"] and len(kept) == 1
    assert notes == [(f"{MACHINE} axis A probing visit 1: no date (its probing table has no "
                      "started_at): left out of the axis's probing series")]
