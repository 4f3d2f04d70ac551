"""The product finds its own files (the twin's presets, the hidden-effect scenarios, the example
data) where it is installed, whatever folder it runs in: a user's folder holding an
``experiments/`` folder of its own (a package or not, with a ``presets`` folder or not) neither
breaks ``bl.simulate`` nor stands in for the shipped presets."""

from __future__ import annotations

import fnmatch
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]
SHIPPED_PRESETS = sorted(p.stem for p in (REPO / "experiments" / "presets").glob("*.toml"))
# The user's own demo preset: one visit instead of the shipped six (1440 readings, not 8640).
USERS_DEMO = "[fleet]\nvisits = 1\n"
SHIPPED_DEMO_READINGS = 8640   # the shipped demo preset: 6 visits x 1440 readings

CODE = """
import json
import backlash as bl
from models.physics import PRESETS, SHIPPED
from pipeline.workflows.hidden_effects import SCENARIOS

result = bl.simulate(preset="demo", seed=3, track=False)
print(json.dumps({"presets": sorted(PRESETS), "shipped": str(SHIPPED),
                  "preset_folders": sorted({str(p.parent) for p in PRESETS.values()}),
                  "scenarios": str(SCENARIOS), "scenarios_exist": SCENARIOS.is_file(),
                  "readings": len(result.readings),
                  "deviation_sum": round(float(result.readings["deviation_um"].sum()), 3)}))
"""


def users_folder(root: Path, layout: str) -> Path:
    """A working folder with an ``experiments/`` folder of the user's own."""
    mine = root / "experiments"
    mine.mkdir(parents=True)
    (mine / "my_campaign.toml").write_text(USERS_DEMO)
    if layout in ("package", "package+presets"):
        (mine / "__init__.py").write_text("")
    if layout in ("presets", "package+presets"):
        (mine / "presets").mkdir()
        (mine / "presets" / "demo.toml").write_text(USERS_DEMO)
        (mine / "presets" / "mine.toml").write_text(USERS_DEMO)
    return root


def run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """Run in ``cwd``, the checkout on the path as the other subprocess tests have it: the
    working folder still comes first for ``python -c`` and ``python -m``, as for a user."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "MLFLOW_DISABLE_TELEMETRY": "true"}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
                          check=False)


@pytest.fixture(scope="module")
def shipped_demo():
    import backlash as bl

    readings = bl.simulate(preset="demo", seed=3, track=False).readings
    return len(readings), round(float(readings["deviation_um"].sum()), 3)


@pytest.mark.parametrize("layout", ["bare", "package", "presets", "package+presets"])
def test_python_finds_the_shipped_presets_beside_a_users_experiments_folder(
        tmp_path, layout, shipped_demo):
    cwd = users_folder(tmp_path, layout)
    done = run([sys.executable, "-c", CODE], cwd)
    assert done.returncode == 0, done.stderr[-2000:]
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["presets"] == SHIPPED_PRESETS and "mine" not in found["presets"]
    assert found["preset_folders"] == [str(REPO / "experiments" / "presets")]
    assert found["shipped"] == str(REPO / "experiments")
    assert found["scenarios"] == str(REPO / "experiments" / "hidden_effect_scenarios.toml")
    assert found["scenarios_exist"]
    # the shipped demo, not the user's one-visit file of the same name
    assert (found["readings"], found["deviation_sum"]) == shipped_demo
    assert found["readings"] == SHIPPED_DEMO_READINGS


@pytest.mark.parametrize("entry", ["script", "module"])
def test_the_command_finds_the_shipped_presets_beside_a_users_experiments_folder(
        tmp_path, entry, shipped_demo):
    cwd = users_folder(tmp_path, "package+presets")
    script = Path(sys.executable).with_name("backlash")
    if entry == "script":
        if not script.is_file():
            pytest.skip("no installed backlash script beside this Python")
        argv = [str(script)]
    else:
        argv = [sys.executable, "-m", "pipeline.cli"]
    done = run([*argv, "simulate", "--preset", "demo", "--seed", "3", "--out", "twin",
                "--no-track"], cwd)
    assert done.returncode == 0, done.stderr[-2000:]
    readings = pd.read_csv(cwd / "twin" / "readings.csv")
    assert (len(readings), round(float(readings["deviation_um"].sum()), 3)) == shipped_demo
    # the user's files are left as they were
    assert (cwd / "experiments" / "presets" / "demo.toml").read_text() == USERS_DEMO


def test_a_users_presets_folder_is_not_offered_as_presets(tmp_path):
    cwd = users_folder(tmp_path, "package+presets")
    code = "import backlash as bl; bl.simulate(preset='mine', track=False)"
    done = run([sys.executable, "-c", code], cwd)
    assert done.returncode != 0
    assert "unknown preset 'mine'" in done.stderr
    assert ", ".join(SHIPPED_PRESETS) in done.stderr


def test_the_package_ships_the_files_the_product_loads():
    """Every file the code loads (presets, scenarios) and every example data file matches the
    package data of pyproject.toml, and lies in a package setuptools finds."""
    from setuptools import find_namespace_packages

    from models.physics import PRESETS, SHIPPED
    from pipeline.workflows.hidden_effects import SCENARIOS

    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = config["package-data"]["*"]
    packages = set(find_namespace_packages(str(REPO), include=config["packages"]["find"]["include"]))
    data = [p for p in (SHIPPED / "data").rglob("*")
            if p.is_file() and p.suffix not in (".py", ".md", ".pyc")]
    loaded = [*PRESETS.values(), SCENARIOS]
    assert len(PRESETS) == len(SHIPPED_PRESETS) >= 8 and data
    for path in [*loaded, *data]:
        relative = path.relative_to(REPO)
        assert any(fnmatch.fnmatch(path.name, p) for p in patterns), relative
        assert ".".join(relative.parent.parts) in packages, relative
