"""Who tested with what: the ``[report]`` table of a meta file, printed on every report page.

A readings file holds the machine's figures, not who stands behind them: the operator, the
instrument and its calibration, the environment sensors and theirs. A test report is signed
against them, so every page prints them above its signature block.
``backlash report --meta META.toml`` reads its ``[report]`` table: ``operator``,
``organisation``, ``instrument``, ``instrument_serial``, ``instrument_calibrated_on`` (a date),
``remarks`` and one ``[[report.sensors]]`` table per environment sensor (``name``, ``serial``,
``calibrated_on``); ``experiments/data/report_meta.toml`` is an example, ``docs/report.md``
the reference.

The table is read by the one configuration reader (``features.readings.config``): an unknown
key, a missing one or a value of the wrong kind is one line naming the file and the key.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field

from features.readings.errors import InputError

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

    def check(self, file=None) -> None:
        """Refuse blank names: a page would print an empty operator or instrument."""
        for key in ("operator", "instrument", "instrument_serial"):
            if not getattr(self, key).strip():
                raise InputError("is empty; expected text", file=file, column=f"report.{key}")
        for i, sensor in enumerate(self.sensors, start=1):
            if not sensor.name.strip():
                raise InputError("is empty; expected the sensor's name", file=file,
                                 column=f"report.sensors[{i}].name")

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
