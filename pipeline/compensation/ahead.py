"""Compensation ahead of wear: the operating hours a wear map's table is forecast for.

Backlash grows with operating hours between maintenance visits, so a table made for the
visit's backlash is right only on the day of the visit and lags the wear until the next one.
Over an interval of I hours in which backlash grows at w(x), a table for the hours h_c leaves
|w(x)| |h - h_c| at hours h; averaged over the interval this is smallest for h_c in its middle
(w I / 4 against w I / 2 for the table frozen at the visit). The default point is therefore the
middle of the next maintenance interval: the axis's last visit plus half its mean interval
between visits, both in operating hours (``models.wear.wear_map.WearMap.visit_hours``).

A date becomes operating hours through the axis's usage rate when the model records it: its
``model.json`` key ``usage``, per machine axis ``{"machine_id", "axis", "last_date",
"last_hours", "hours_per_day"}``.
"""

from __future__ import annotations

import datetime as dt

import numpy as np

from features.readings.errors import InputError


def wear_map_of(model, why: str):
    """The wear map inside the trained ``model`` (``models.serving.registry.TrainedModel``) when it can
    forecast, else an ``InputError`` naming ``why`` (the parameter that needs it)."""
    from models.wear.wear_map import WearMap

    estimator = model.estimator
    if not isinstance(estimator, WearMap):
        raise InputError(f"needs a wear-map model (backlash train DATA --model wear-map); this "
                         f"model is {model.name!r}, which has no operating-hours term",
                         parameter=why)
    if not estimator.can_forecast_:
        raise InputError("the wear map was trained without operating hours (or with one value "
                         "of them): it has no wear term to forecast", parameter=why)
    return estimator


def known_axes(model, machine=None, axis=None) -> list[tuple[str, str]]:
    """The machine axes a wear map knows, those named by ``machine`` and ``axis`` (names or
    lists of names) only; one error line when the selection names none of them."""
    wear = model.estimator
    axes = [tuple(map(str, k)) for k in (wear.axes_ or [])]
    if not axes:  # trained on data that name no machine axis
        axes = [(str(model.meta.get("machine_id", model.name)), str(axis or "X").upper())]
        return axes if machine is None else _selected(axes, machine, None)
    return _selected(axes, machine, axis)


def _selected(axes, machine, axis) -> list[tuple[str, str]]:
    machines = _names(machine)
    names = [a.upper() for a in _names(axis)]
    chosen = [(m, a) for m, a in axes if (not machines or m in machines)
              and (not names or a.upper() in names)]
    if not chosen:
        known = ", ".join(f"{m} {a}" for m, a in axes)
        raise InputError(f"selects no machine axis the model knows ({known})",
                         parameter="machine" if machines else "axis")
    return chosen


def _names(value) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return [str(v) for v in value]


def forecast_hours(model, key: tuple[str, str], at_hours=None, at_date=None
                   ) -> tuple[float | None, str]:
    """The operating hours [h] the table of machine axis ``key`` is forecast for, and a note
    saying where they come from: ``at_hours`` as given, ``at_date`` through the axis's usage
    rate, else the middle of the next maintenance interval (module docstring); None when
    that is unknown (fewer than two visits recorded)."""
    if at_hours is not None:
        return float(at_hours), f"forecast for {float(at_hours):g} operating hours (given)"
    if at_date is not None:
        return _hours_at(model, key, at_date)
    hours = model.estimator.visit_hours(key if model.estimator.axes_ else None)
    if len(hours) < 2:  # a model saved without them: the training median, as before
        return None, ("the model does not record two or more visits' operating hours, so "
                      "the middle of the next maintenance interval is unknown: give at_hours")
    step = float(np.mean(np.diff(hours)))
    middle = float(hours[-1]) + step / 2
    return middle, (f"forecast for {middle:g} operating hours, the middle of the next "
                    f"maintenance interval (last visit at {hours[-1]:g} h, visits "
                    f"{step:g} h apart on average)")


def parse_date(value) -> dt.date:
    """``YYYY-MM-DD`` (or a date) -> date; one error line otherwise."""
    if isinstance(value, dt.datetime):
        return value.date()
    if isinstance(value, dt.date):
        return value
    try:
        return dt.date.fromisoformat(str(value))
    except ValueError:
        raise InputError(f"{value!r} is not a date YYYY-MM-DD", parameter="at_date") from None


def _hours_at(model, key, at_date) -> tuple[float, str]:
    """Operating hours at ``at_date`` from the axis's recorded usage rate."""
    date = parse_date(at_date)
    usage = {(str(u.get("machine_id")), str(u.get("axis"))): u
             for u in model.meta.get("usage", []) if isinstance(u, dict)}
    record = usage.get(key) or (next(iter(usage.values())) if len(usage) == 1 else None)
    if record is None:
        raise InputError(f"{key[0]} {key[1]}: the model does not record the axis's usage rate "
                         "(operating hours per day since a dated visit), so a date cannot be "
                         "turned into operating hours: give --at-hours", parameter="at_date")
    try:
        last = parse_date(record["last_date"])
        rate, hours = float(record["hours_per_day"]), float(record["last_hours"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{key[0]} {key[1]}: model.json key 'usage' needs last_date, "
                         "last_hours and hours_per_day", parameter="at_date") from None
    days = (date - last).days
    if days < 0:
        raise InputError(f"{date} is before the axis's last visit ({last}): a table ahead of "
                         "wear is for a later date", parameter="at_date")
    at = hours + rate * days
    return at, (f"forecast for {at:g} operating hours on {date} (last visit {last} at "
                f"{hours:g} h, {rate:g} h a day)")
