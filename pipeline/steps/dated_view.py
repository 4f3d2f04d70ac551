"""What a date-based view (``fleet``, ``drift``) sees: the dated tests up to its day.

Both views place every visit on the calendar. A test without a start date (``started_at``)
cannot be placed: it is left out, with one note naming the tests, rather than stopping the
view. A view is computed as of a day (``as_of``, default today, UTC) and measures what is
overdue against that day; it sees the tests started by the end of that day, as it would have
been seen then. Today is no exception: a test dated ahead (a mistyped year, a simulated plan
ingested with ``--allow-future``) would otherwise be taken for the axis's latest visit and
hide an overdue one.
"""

from __future__ import annotations

import datetime as dt

from features.readings.errors import InputError

MAX_NAMED = 8  # tests named in a note; the rest are counted


def as_of_date(value, parameter: str = "as_of") -> dt.date:
    """The day a view is computed as of: ``value`` as a date (a ``datetime.date``, a
    timestamp, or text ``YYYY-MM-DD``), today (UTC) when None.

    Raises
    ------
    InputError
        Text that is not a calendar date ``YYYY-MM-DD``, naming the parameter.
    """
    if value is None:
        return dt.datetime.now(dt.UTC).date()
    if isinstance(value, dt.datetime):  # pandas.Timestamp is one too
        return value.date()
    if isinstance(value, dt.date):
        return value
    text = str(value).strip()
    try:
        if len(text) != 10:
            raise ValueError(text)
        return dt.date.fromisoformat(text)
    except ValueError:
        raise InputError(f"{text!r}: expected a calendar date YYYY-MM-DD, e.g. 2026-03-31",
                         parameter=parameter) from None


def dated_view(readings, as_of: dt.date | None, source: str = "readings"):
    """The readings a view computed as of ``as_of`` sees, and its notes.

    Tests without ``started_at`` are left out (one note naming them), so are tests started
    after the end of the day ``as_of`` (UTC; one note counting them). ``as_of`` None keeps
    every dated test (for a caller that has no day). Readings without a ``started_at`` column
    are returned as they are (the view says what it needs).

    Raises
    ------
    InputError
        No test is left: none has a date, or none started by ``as_of``.
    """
    import pandas as pd

    if "started_at" not in readings.columns:
        return readings, []
    notes = []
    undated = readings["started_at"].isna().to_numpy()
    if undated.any():
        names = sorted(set(readings.loc[undated, "test_id"].astype(str)))
        shown = ", ".join(names[:MAX_NAMED]) + (f" and {len(names) - MAX_NAMED} more"
                                                if len(names) > MAX_NAMED else "")
        notes.append(f"{len(names)} test(s) without a start date (started_at) left out of the "
                     f"date-based view: {shown}")
        if undated.all():
            raise InputError("no test has a start date (started_at): the view places every "
                             "visit on the calendar", file=source, column="started_at")
        readings = readings[~undated]
    if as_of is None:
        return readings, notes
    started = pd.to_datetime(readings["started_at"], utc=True)
    later = (started >= pd.Timestamp(as_of + dt.timedelta(days=1), tz="UTC")).to_numpy()
    if later.all():
        raise InputError(f"no test started by {as_of.isoformat()}", parameter="as_of")
    if later.any():
        notes.append(f"{readings.loc[later, 'test_id'].nunique()} test(s) started after "
                     f"{as_of.isoformat()} left out: the view is computed as of that day")
        readings = readings[~later]
    return readings, notes


def kept_view(source, readings, as_of: dt.date):
    """The rows of the dated view ``readings`` (every machine axis) of the machine axes that
    ``source``'s selection keeps (``pipeline.steps.source.Source``).

    Raises
    ------
    InputError
        None of them has a test started by ``as_of``.
    """
    kept = source.kept(readings)
    if kept.empty:
        raise InputError(f"no test of {source.selection.text} started by {as_of.isoformat()}",
                         parameter="as_of")
    return kept
