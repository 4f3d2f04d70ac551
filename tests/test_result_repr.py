"""Results that read well: a short ``repr`` of every result (the data's name, key figures,
shapes), and notes that name the caller's line rather than the library's."""

from __future__ import annotations

import importlib
import warnings
from dataclasses import is_dataclass
from pathlib import Path

import numpy as np
import pandas as pd

import backlash as bl
from features.readings.errors import BacklashWarning
from pipeline.results import REPR_CHARS, Result
from pipeline.workflows import NAMES

DATA = Path(__file__).parents[1] / "experiments" / "data"
ESS = DATA / "ecmc" / "ess_mcu1025_ISO230.dat"


def result_classes() -> list[type]:
    """Every Result subclass the jobs define."""
    found = set()
    for name in NAMES:
        module = importlib.import_module(f"pipeline.workflows.{name.replace('-', '_')}")
        found |= {v for v in vars(module).values()
                  if isinstance(v, type) and issubclass(v, Result) and v is not Result}
    return sorted(found, key=lambda c: c.__name__)


def test_every_result_class_keeps_the_short_repr():
    classes = result_classes()
    assert len(classes) >= len(NAMES) - 2  # a few jobs share a result class
    assert all(is_dataclass(c) and c.__repr__ is Result.__repr__ for c in classes), [
        c.__name__ for c in classes if c.__repr__ is not Result.__repr__]


def test_an_iso_result_names_its_data_tests_and_shapes():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        result = bl.iso(ESS)
    text = repr(result)
    # the real file: one test of 5 targets, two outlier readings in cycle 1 (two notes)
    assert text.startswith("IsoResult(data='ess_mcu1025_ISO230.dat', tests=1, targets=5x")
    assert "figures=1x" in text and "outliers=2x" in text and text.endswith("notes=2)")
    assert len(text) < 200 and str(result) == text


def test_a_result_of_large_frames_stays_within_the_limit():
    from pipeline.workflows.predict import PredictionResult

    big = pd.DataFrame(np.zeros((100_000, 12)), columns=[f"c{i}" for i in range(12)])
    result = PredictionResult(predictions=big, model="x" * 500, notes=["n"] * 1000)
    text = repr(result)
    assert text.startswith("PredictionResult(predictions=100000x12, model='xxx")
    assert len(text) <= REPR_CHARS + len("PredictionResult()")
    assert "x" * 37 + "...'" in text and "x" * 38 not in text  # cut at 40 characters
    many = PredictionResult(predictions=big, model="m", notes=["n"] * 1000)
    assert repr(many) == "PredictionResult(predictions=100000x12, model='m', notes=1000)"


def test_a_note_names_the_callers_line():
    plan = pd.read_csv(DATA / "plan_next_visit.csv")
    model = bl.train(DATA / "twin" / "readings.csv", model="wear-map").trained
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = _line() + 1
        bl.predict(model, plan=plan.assign(feed_mm_min=20_000.0))
    notes = [w for w in caught if issubclass(w.category, BacklashWarning)]
    assert notes and all(w.filename == __file__ and w.lineno == line for w in notes), [
        (w.filename, w.lineno) for w in notes]


def _line() -> int:
    import sys

    return sys._getframe(1).f_lineno


def test_a_library_between_two_product_frames_is_not_the_caller(tmp_path, monkeypatch):
    """A note issued in a callback that pandas calls for a product function names the line
    that called the product, not pandas' line."""
    import importlib.util

    from features.readings import errors

    package = tmp_path / "product"
    package.mkdir()
    (package / "job.py").write_text(
        "import pandas as pd\n"
        "from features.readings.errors import note\n\n\n"
        "def noted(value):\n"
        "    note('from inside a pandas callback')\n"
        "    return value\n\n\n"
        "def run():\n"
        "    return pd.Series([1.0]).apply(noted)\n", encoding="utf-8")
    spec = importlib.util.spec_from_file_location("product_job", package / "job.py")
    job = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(job)
    monkeypatch.setattr(errors, "PACKAGES", (*errors.PACKAGES, str(package.resolve())))
    errors._inside.cache_clear()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            line = _line() + 1
            job.run()
    finally:
        errors._inside.cache_clear()
    assert [(w.filename, w.lineno) for w in caught] == [(__file__, line)]
