"""Headless Chromium for the browser tests: where it is, how it starts on a closed network,
and why a test is skipped (opt-in: BACKLASH_BROWSER_TESTS=1; `.ci/run` installs Chromium)."""

from __future__ import annotations

import os
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
# as root, no GPU, no network beyond the page on disk
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def skip_reason() -> str | None:
    """Why a browser test cannot run here, or None."""
    if os.environ.get("BACKLASH_BROWSER_TESTS") != "1":
        return "set BACKLASH_BROWSER_TESTS=1 to run the headless Chromium test"
    if not CHROMIUM.exists():
        return f"{CHROMIUM} not found (apt-get install chromium)"
    return None
