"""The ranking report renders in a real browser (opt-in: BACKLASH_BROWSER_TESTS=1)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from browser import CHROMIUM, FLAGS, skip_reason

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    reason = skip_reason()
    if reason:
        print(f"\nbrowser test skipped: {reason}")
        pytest.skip(reason)
    from models.influence import explain
    from pipeline.reports.rank_report import write_rank_report

    rng = np.random.default_rng(0)
    n = 160
    X = pd.DataFrame({"target": rng.choice(np.linspace(25, 325, 7), n),
                      "feed_mm_min": rng.choice([200.0, 500.0, 1200.0], n),
                      "pressure_hpa": rng.normal(1013, 5, n),
                      "humidity_pct": rng.normal(45, 8, n)})
    y = 2 + 0.008 * X["target"] + 0.0015 * X["feed_mm_min"] + rng.normal(0, 0.3, n)
    result = explain(X, y, n_boot=50, n_repeats=2, dropcolumn=False)
    out = tmp_path_factory.mktemp("rank_report")
    return write_rank_report(result, out, source="synthetic")["html"]


def test_every_image_in_the_page_exists(report):
    page = report.read_text(encoding="utf-8")
    sources = re.findall(r'<img[^>]*\bsrc="([^"]+)"', page)
    assert len(sources) == 4  # effects, ANOVA, confusion matrix, the other views
    for src in sources:
        if src.startswith("data:image/png;base64,"):
            continue
        assert not re.match(r"^[a-z]+:", src), f"absolute or remote image {src}"
        path = report.parent / src
        assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", src


def test_headless_chromium_screenshot_is_not_blank(report, tmp_path):
    shot = tmp_path / "report.png"
    command = [str(CHROMIUM), *FLAGS,
               f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
               "--window-size=1200,2000", report.as_uri()]
    done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=120)
    assert shot.is_file(), f"no screenshot; chromium said: {done.stderr[-800:]}"
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3]
    assert pixels.shape[:2] == (2000, 1200)
    # A page with text, tables and four figures: many distinct colours, and a good share
    # of the page is not background white.
    distinct = np.unique((pixels * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(distinct) > 200
    assert (pixels.mean(axis=2) < 0.9).mean() > 0.05
    # The figures drew: the driver bars of the effect chart (#1f5f99) cover thousands of
    # pixels, far more than the page's own use of that colour (a 4-pixel border).
    bar = np.abs(pixels * 255 - np.array([31, 95, 153])).max(axis=2) < 12
    assert bar.sum() > 5000
