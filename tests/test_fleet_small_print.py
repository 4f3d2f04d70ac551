"""Honest small print: a trend from two visits says its interval cannot be estimated; the
scalar of ``compensate`` is the reversal compensation, printed beside the axis's lost motion
(the value ``fleet`` shows). Checked on the independently written fleet
(tests/independent_fleet.py)."""

from __future__ import annotations

import re
import warnings

import pytest
from independent_fleet import fleet as independent

import backlash as bl
from features.readings.errors import BacklashWarning
from pipeline.workflows.compensate import compensate
from pipeline.workflows.drift import drift
from pipeline.workflows.fleet import fleet

AS_OF = "2025-12-31"


@pytest.fixture(scope="module")
def two():
    """The fleet after its second visit (M5 joins later: four machines, eight axes)."""
    return bl.validate(independent(0, visits=2)[0])


def test_a_trend_from_two_visits_has_no_interval(two, tmp_path):
    with pytest.warns(BacklashWarning, match="comes from two visits; its interval cannot be "
                                             "estimated"):
        view = fleet(two, threshold_um=8.0, as_of=AS_OF, out=tmp_path / "site")
    for v in view.axes:
        a = v.to_dict()
        assert a["slope_um_per_month"] is not None and a["slope_interval"] == [None, None]
        page = (tmp_path / "site" / v.page).read_text(encoding="utf-8")
        assert "interval cannot be estimated from two visits" in page
        assert not re.search(r"\[(-?[\d.]+), \1\]", page)  # no zero-width interval
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        result = drift(two, as_of=AS_OF)
    assert all(s["slope_interval"] == [None, None] for s in result.to_dict()["series"])
    text = result.write(tmp_path / "drift")["html"].read_text(encoding="utf-8")
    assert "(interval cannot be estimated from two visits)" in text


def test_three_visits_give_an_interval(two):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        view = fleet(bl.validate(independent(0, visits=3)[0]), as_of=AS_OF)
    for a in view.to_dict()["axes"]:
        low, high = a["slope_interval"]
        assert low < high


def test_compensate_prints_the_reversal_compensation_beside_the_lost_motion(two):
    """A direct system (M1: linear scale): the linear tests hide most of the lost motion, so
    the scalar written is far below the backlash fleet gives the axis."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        view = fleet(two, as_of=AS_OF)
        lost = {(a["machine_id"], a["axis"]): a["backlash_um"] for a in view.to_dict()["axes"]}
        for machine in ("M1", "M3"):  # direct, indirect (rotary encoder)
            one = two[(two["machine_id"] == machine) & (two["axis"] == "X")]
            result = compensate(one, controller="csv")
            line = result.summary()[0]
            match = re.fullmatch(rf"{machine} X \(measured\): reversal compensation ([\d.]+) um; "
                                 r"the axis's lost motion ([\d.]+) um \(docs/backlash.md\), "
                                 r"11 targets", line)
            assert match, line
            scalar, motion = map(float, match.groups())
            assert motion == pytest.approx(lost[(machine, "X")], abs=1e-3)
            assert result.to_dict()["axes"][0]["lost_motion_um"] == pytest.approx(motion,
                                                                                abs=1e-3)
            if machine == "M1":
                assert scalar < 0.3 * motion
            else:  # the encoder's tests show the whole lost motion
                assert scalar == pytest.approx(motion, rel=0.25)
