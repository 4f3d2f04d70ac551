"""``pipeline.tracking.background.BackgroundTask``: work done in a forked child gives back its value
or its error, as the same work done in-process does."""

from __future__ import annotations

import os

import pytest

from features.readings.errors import InputError
from pipeline import tracking
from pipeline.tracking import background
from pipeline.tracking.background import BackgroundTask


@pytest.fixture(params=[False, True], ids=["in-process", "forked"])
def forking(request, monkeypatch):
    """Whether the task runs in a child: allowed here, and possible in this test process
    (another test may have left a thread running, and a process with threads never forks)."""
    monkeypatch.setitem(tracking._fork, "allowed", request.param)
    return background._can_fork(mlflow_free=False)


def test_the_value_comes_back(forking):
    parent = os.getpid()
    with BackgroundTask(lambda: {"pid": os.getpid(), "values": [1, 2.5, "a"]}) as task:
        value = task.result()
    assert value["values"] == [1, 2.5, "a"]
    assert (value["pid"] != parent) == forking


def test_an_input_error_stays_an_input_error(forking):
    def work():
        raise InputError("bad figure", parameter="figures")

    with BackgroundTask(work) as task, pytest.raises(InputError, match="bad figure"):
        task.result()


def test_a_bug_is_raised_with_its_traceback(forking):
    with BackgroundTask(lambda: 1 / 0) as task, pytest.raises((RuntimeError,
                                                                 ZeroDivisionError)) as err:
        task.result()
    assert "ZeroDivisionError" in (str(err.value) if forking else err.type.__name__)


def test_leaving_on_an_error_stops_the_child(tmp_path, monkeypatch):
    monkeypatch.setitem(tracking._fork, "allowed", True)
    marker = tmp_path / "late"

    def work():
        import time

        time.sleep(5)
        marker.write_text("written after the command failed")

    with pytest.raises(KeyError), BackgroundTask(work):
        raise KeyError("the command failed")
    assert not marker.exists()
