"""The drift report renders in a real browser: page shell, table and figure (opt-in:
BACKLASH_BROWSER_TESTS=1 with /usr/bin/chromium; `.ci/run` sets both up)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = Path("/usr/bin/chromium")
pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def drift_page(tmp_path_factory) -> Path:
    if os.environ.get("BACKLASH_BROWSER_TESTS") != "1":
        pytest.skip("set BACKLASH_BROWSER_TESTS=1 to run the headless Chromium test")
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} not found (apt-get install chromium)")
    import pandas as pd

    from features.visits import DAYS_PER_MONTH
    from models.condition.drift import analyse_series
    from models.condition.maintenance import axis_forecast
    from pipeline.reports.drift_report import write_drift_report

    months = np.arange(12.0)
    visits = pd.DataFrame({
        "machine_id": "M1", "axis": "X", "visit": [f"v{i:02d}" for i in range(12)],
        "date": pd.Timestamp("2025-01-10", tz="UTC") + pd.to_timedelta(months * DAYS_PER_MONTH, "D"),
        "n_tests": 1, "n_points": 6, "target_kind": "iso",
        "backlash_um": 2 + 0.3 * months + np.random.default_rng(0).normal(0, 0.05, 12),
        "backlash_u_um": 0.1, "reversal_mean_um": -(2 + 0.3 * months),
        "reversal_max_um": 2 + 0.3 * months})
    series = [analyse_series(visits, threshold_um=6.0)]  # crossing within months: alert
    assert [a["kind"] for a in series[0].alerts] == ["crossing_soon"]
    out = tmp_path_factory.mktemp("drift_report")
    return write_drift_report([axis_forecast(s) for s in series], out, source="synthetic")["html"]


def test_drift_report_screenshot_shows_the_figure(drift_page, tmp_path):
    shot = tmp_path / "drift.png"
    command = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
               "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
               f"--screenshot={shot}", "--window-size=1100,1400", drift_page.as_uri()]
    done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=120)
    assert shot.is_file(), f"no screenshot; chromium said: {done.stderr[-800:]}"
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3] * 255
    assert pixels.shape[:2] == (1400, 1100)
    # The page drew its figure: the series' markers (C0, #1f77b4) and the trend line (C1,
    # #ff7f0e) cover many pixels; the shell itself uses neither colour.
    for colour in ([31, 119, 180], [255, 127, 14]):
        assert (np.abs(pixels - np.array(colour)).max(axis=2) < 20).sum() > 300, colour
    # The alert panel of the shell (.alert background #fff4f0) is there: the series alerts.
    assert (np.abs(pixels - np.array([255, 244, 240])).max(axis=2) < 3).sum() > 2000
