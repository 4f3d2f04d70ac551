"""Who tested with what: the ``[report]`` table of a meta file, printed on every report page.

A readings file holds the machine's figures, not who stands behind them: the operator, the
instrument and its calibration, the environment sensors and theirs. A test report is signed
against them, so every page prints them above its signature block.
``backlash report --meta META.toml`` reads its ``[report]`` table: ``operator``,
``organisation``, ``instrument``, ``instrument_serial``, ``instrument_calibrated_on`` (a date),
``remarks`` and one ``[[report.sensors]]`` table per environment sensor (``name``, ``serial``,
``calibrated_on``); ``experiments/data/report_meta.toml`` is an example, ``docs/report.md``
the reference.

A calibration is checked against its dates: one dated after today is refused as it is read (no
one calibrated an instrument on a day still to come), one dated after a test it measured is
refused and one older than ``calibration_valid_months`` (default 12) at the test's date is
noted (``ReportMeta.against_tests``).

The table is read by the one configuration reader (``features.readings.config``): an unknown
key, a missing one or a value of the wrong kind is one line naming the file and the key.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field

from features.readings.errors import InputError

# How long a calibration holds when the meta file does not say [months]: a yearly interval,
# the usual one of a laser interferometer and its environment sensors.
CALIBRATION_VALID_MONTHS = 12

# The fields a page prints, by the label it gives them.
LABELS = {"operator": "operator", "organisation": "organisation", "instrument": "instrument",
          "instrument_serial": "serial no.", "instrument_calibrated_on": "calibrated on"}


@dataclass
class Sensor:
    """One environment sensor (air or machine temperature, pressure, humidity)."""

    name: str
    calibrated_on: dt.date
    serial: str = ""

    def text(self) -> str:
        serial = f" (serial {self.serial})" if self.serial else ""
        return f"{self.name}{serial}, calibrated on {self.calibrated_on.isoformat()}"


@dataclass
class ReportMeta:
    """The ``[report]`` table: operator, instrument and its calibration, sensors, remarks."""

    operator: str
    instrument: str
    instrument_serial: str
    instrument_calibrated_on: dt.date
    organisation: str = ""
    sensors: list[Sensor] = field(default_factory=list)
    remarks: str = ""
    calibration_valid_months: int = CALIBRATION_VALID_MONTHS

    def check(self, file=None, today: dt.date | None = None) -> None:
        """Refuse blank names (a page would print an empty operator or instrument), a
        validity that is not a whole number of months >= 1, and a calibration dated after
        ``today`` (default the computer's date)."""
        for key in ("operator", "instrument", "instrument_serial"):
            if not getattr(self, key).strip():
                raise InputError("is empty; expected text", file=file, column=f"report.{key}")
        for i, sensor in enumerate(self.sensors, start=1):
            if not sensor.name.strip():
                raise InputError("is empty; expected the sensor's name", file=file,
                                 column=f"report.sensors[{i}].name")
        if not 1 <= self.calibration_valid_months <= 1200:
            raise InputError(f"{self.calibration_valid_months} is not a validity; expected whole "
                             "months between 1 and 1200", file=file,
                             column="report.calibration_valid_months")
        today = today or dt.date.today()
        for key, what, day in self.calibrations():
            if day > today:
                raise InputError(f"the {what} is dated {day.isoformat()}, after today "
                                 f"({today.isoformat()}); expected the date of its last "
                                 "calibration", file=file, column=key)
        self._file = file

    def calibrations(self) -> list[tuple[str, str, dt.date]]:
        """(key, what, date) of the instrument's and every sensor's calibration."""
        out = [("report.instrument_calibrated_on", "instrument's calibration",
                self.instrument_calibrated_on)]
        out += [(f"report.sensors[{i}].calibrated_on", f"calibration of sensor {s.name!r}",
                 s.calibrated_on) for i, s in enumerate(self.sensors, start=1)]
        return out

    def against_tests(self, readings=None, today: dt.date | None = None) -> list[str]:
        """Check every calibration against the dates of the tests the report signs.

        Parameters
        ----------
        readings : DataFrame, optional
            The tests' readings: their dates are the days of ``started_at`` (else
            ``measured_at``). Without either, the tests are taken as made ``today``.
        today : datetime.date, optional
            The report's date (default the computer's).

        Returns
        -------
        list of str
            One note (also issued, ``features.readings.errors.note``) per calibration older
            than ``calibration_valid_months`` at the latest test's date: the test was made
            with an instrument out of calibration.

        Raises
        ------
        InputError
            A calibration dated after the earliest test (naming the meta file and the key):
            the instrument that measured the test was not yet calibrated as the page says.
        """
        from features.readings.errors import note

        today = today or dt.date.today()
        days = days_of_tests(readings)
        first = min(days) if days else today
        notes = []
        for key, what, day in self.calibrations():
            if day > first:
                raise InputError(f"the {what} is dated {day.isoformat()}, after the test of "
                                 f"{first.isoformat()}; expected the calibration in force "
                                 "when the test was made", file=getattr(self, "_file", None),
                                 column=key)
            due = add_months(day, self.calibration_valid_months)
            late = [d for d in days if d > due]
            expired = (f"the {what} of {day.isoformat()} expired on {due.isoformat()} (valid "
                       f"{self.calibration_valid_months} months)")
            if late:
                tests = (f"the test of {late[0].isoformat()} was" if len(late) == 1 else
                         f"{len(late)} test days, {late[0].isoformat()} to "
                         f"{late[-1].isoformat()}, were")
                notes.append(f"{expired}: {tests} made out of calibration")
            elif not days and due < today:
                notes.append(f"{expired}, before today ({today.isoformat()}); the tests state no "
                             "date (started_at): check they were made before it expired")
        for text in notes:
            note(text)
        return notes

    def pairs(self) -> list[tuple[str, str]]:
        """(label, value) of every field given, in ``LABELS`` order, then the sensors."""
        out = []
        for key, label in LABELS.items():
            value = getattr(self, key)
            text = value.isoformat() if isinstance(value, dt.date) else str(value)
            if text:
                out.append((label, text))
        out += [("environment sensor", s.text()) for s in self.sensors]
        return out


def add_months(day: dt.date, months: int) -> dt.date:
    """``day`` ``months`` later (the month's last day where it has fewer days)."""
    import calendar

    month = day.month - 1 + months
    year, month = day.year + month // 12, month % 12 + 1
    return dt.date(year, month, min(day.day, calendar.monthrange(year, month)[1]))


def days_of_tests(readings) -> list[dt.date]:
    """The days (UTC) the tests of ``readings`` were made: each test's earliest
    ``started_at``, else ``measured_at``; empty when the readings state neither."""
    import pandas as pd

    if readings is None:
        return []
    for column in ("started_at", "measured_at"):
        if column in readings:
            when = pd.to_datetime(readings[column], utc=True, errors="coerce").dropna()
            if not when.empty:
                keys = [readings.loc[when.index, k] for k in ("machine_id", "axis", "test_id")
                        if k in readings]
                first = when.groupby(keys).min() if keys else when
                return sorted({t.date() for t in first})
    return []


@dataclass
class MetaFile:
    """A meta file: its one ``[report]`` table."""

    report: ReportMeta


def read_meta(source) -> ReportMeta:
    """The ``[report]`` table of a TOML file (or a dict of the same shape, or a ``ReportMeta``).

    Raises
    ------
    InputError
        An unreadable file, an unknown or missing key, a value of the wrong kind (a date
        written as ``10.02.2026``), a blank operator or instrument.
    """
    from features.readings.config import read_config

    if isinstance(source, ReportMeta):
        source.check()
        return source
    return read_config(source, MetaFile, what="report meta").report
