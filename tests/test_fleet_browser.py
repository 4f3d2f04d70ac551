"""The fleet site renders in a real browser, opened from disk: the fleet table with its
sparklines and an axis page with its charts (opt-in: BACKLASH_BROWSER_TESTS=1 with
/usr/bin/chromium; `.ci/run` sets both up)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from browser import CHROMIUM, FLAGS, skip_reason

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The small twin fleet (2 machines x 2 axes, 6 visits, adjusted at visit 4) with a
    threshold that some axes already exceed: alerts of both kinds."""
    reason = skip_reason()
    if reason:
        print(f"\nbrowser test skipped: {reason}")
        pytest.skip(reason)
    import backlash as bl
    from pipeline.workflows.fleet import fleet

    sim = bl.simulate(preset="fleet", config={"fleet": {"machines": 2, "axes": ["X", "Y"],
                                                        "visits": 6, "adjust_at": [4]}}, seed=0)
    out = tmp_path_factory.mktemp("fleet_site") / "site"
    result = fleet(sim.readings, threshold_um=2.2, out=out)
    assert result.alerts
    return out, result


def _chromium(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    command = [str(CHROMIUM), *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", *args,
               page.as_uri()]
    return subprocess.run(command, check=False, capture_output=True, text=True, timeout=120)


def _screenshot(page: Path, tmp_path: Path, size: tuple[int, int]) -> np.ndarray:
    shot = tmp_path / f"{page.stem}.png"
    done = _chromium(page, tmp_path, f"--screenshot={shot}", f"--window-size={size[0]},{size[1]}")
    assert shot.is_file(), f"no screenshot; chromium said: {done.stderr[-800:]}"
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3] * 255
    assert pixels.shape[:2] == (size[1], size[0])
    return pixels


def _count(pixels: np.ndarray, colour, tolerance: float = 20) -> int:
    return int((np.abs(pixels - np.array(colour)).max(axis=2) < tolerance).sum())


def test_the_browser_shows_every_axis_worst_first_with_its_sparkline(site, tmp_path):
    out, result = site
    done = _chromium(out / "index.html", tmp_path, "--dump-dom")
    dom = done.stdout
    assert "<h1>Fleet backlash</h1>" in dom, done.stderr[-800:]
    pages = re.findall(r'<a href="([^"]+\.html)">', dom)
    assert pages == [a.page for a in result.axes]       # one row per axis, worst first
    assert dom.count('class="spark"') + dom.count("class='spark'") == len(result.axes)
    first = result.axes[0].to_dict()
    assert "above_threshold" in first["alerts"] and first["next_visit_due"] in dom


def test_index_screenshot_shows_the_table_and_the_sparklines(site, tmp_path):
    out, _ = site
    pixels = _screenshot(out / "index.html", tmp_path, (1200, 800))
    distinct = np.unique(pixels.astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(distinct) > 150
    # the sparklines drew: alerting axes in red (#d62728), their forecast bands in orange
    assert _count(pixels, [214, 39, 40]) > 150
    assert _count(pixels, [255, 200, 150], 40) > 150
    # the alerting rows are shaded (#fff4f0), the whole table of them
    assert _count(pixels, [255, 244, 240], 3) > 5000


def test_axis_page_screenshot_shows_history_wear_map_and_iso_chart(site, tmp_path):
    out, result = site
    worst = result.axes[0]
    pixels = _screenshot(out / worst.page, tmp_path, (1200, 2600))
    # history: the visits in blue (#1f77b4), the trend in orange (#ff7f0e)
    assert _count(pixels, [31, 119, 180]) > 300
    assert _count(pixels, [255, 127, 14]) > 150
    # the wear-rate map in green (#2ca02c), the ISO chart's down direction in red (#d62728)
    assert _count(pixels, [44, 160, 44]) > 300
    assert _count(pixels, [214, 39, 40]) > 300
    # the alert panel (#fff4f0) is there
    assert _count(pixels, [255, 244, 240], 3) > 2000


@pytest.fixture(scope="module")
def recorded_site(site, tmp_path_factory):
    """The same fleet in a store with a wear map's forecast of a planned visit and two
    recorded compensations: the records drawn on the site."""
    import warnings

    import backlash as bl
    from pipeline.store.records import record_compensation
    from pipeline.workflows.compensate import compensate
    from pipeline.workflows.fleet import fleet

    _, result = site
    folder = tmp_path_factory.mktemp("recorded_site")
    store = folder / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bl.BacklashWarning)
        bl.write(result.readings, folder / "readings.csv")
        bl.ingest(folder / "readings.csv", store=store)
        bl.train(store, model="wear-map").write(folder / "model")
        last = result.readings[result.readings["visit"] == "06"]
        plan = (last.drop_duplicates(["machine_id", "axis", "target"])
                [["machine_id", "axis", "target", "feed_mm_min", "dwell_s", "operating_hours"]]
                .assign(visit="07", operating_hours=lambda f: f["operating_hours"] + 240.0))
        bl.predict(folder / "model", plan=plan, store=store)
        record_compensation(store, compensate(bl.read(store, until="2026-03-31")),
                            recorded_at="2026-04-01T08:00:00.000000Z")
        record_compensation(store, compensate(store))
        view = fleet(store, threshold_um=2.2, out=folder / "site")
    return folder / "site", view


def test_axis_page_screenshot_shows_the_recorded_forecast_and_compensations(recorded_site,
                                                                           tmp_path):
    out, view = recorded_site
    worst = view.axes[0]
    assert worst.forecasts and len(worst.compensations) == 2
    pixels = _screenshot(out / worst.page, tmp_path, (1200, 3600))
    # the recorded forecast (#9467bd) on the history chart, larger than its legend key
    assert _count(pixels, [148, 103, 189]) > 60
    # the compensation history: the earlier table in grey (#b0b4bb), the latest in blue
    assert _count(pixels, [176, 180, 187], 6) > 200
    index = _screenshot(out / "index.html", tmp_path, (1600, 800))
    assert _count(index, [148, 103, 189]) > 10 * len(view.axes)  # one in each sparkline
