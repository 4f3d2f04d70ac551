"""Each extension point is its record: a format, a controller, a predictor, a physical effect
and a job added from a package of their own (one module each, registered through the
registries' ``register``) appear in the command line, the Python API and the manual's tables
with no other file touched, and go again with ``unregister``."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings import layouts, schema
from models.physics import effects
from models.serving import registry
from pipeline import compensation, workflows

ROOT = Path(__file__).resolve().parents[1]
TWIN = ROOT / "experiments" / "data" / "twin" / "readings.csv"

# The extension package: one module per kind, and ``register()`` / ``unregister()`` calling
# each registry's own, as a site's package of additions would.
PACKAGE = {
    "__init__.py": '''
        """A site's additions to backlash-pipeline: one of each kind."""

        from features.readings import layouts
        from models.serving import registry
        from models.physics import effects
        from pipeline import compensation, workflows


        def register():
            from sitex import columns, clearance, mean, plain

            layouts.register(columns.LAYOUT)
            compensation.register(plain.CONTROLLER)
            registry.register(mean.PREDICTOR)
            effects.register(clearance.site_clearance, **clearance.RECORD)
            workflows.register(workflows.Workflow(
                "site-spread", "Spread of every test's deviations [um] (a site's own job).",
                inputs=("data",), module_name="sitex.spread"))


        def unregister():
            workflows.unregister("site-spread")
            effects.unregister("site_clearance")
            registry.unregister("site-mean")
            compensation.unregister("plain")
            layouts.unregister("columns")
        ''',
    "columns.py": '''
        """A readings table with one column per direction and cycle: pos,fwd1,..,bwd1,.."""

        import numpy as np
        import pandas as pd

        from features.readings.layouts import Layout


        def read_columns(path):
            wide = pd.read_csv(path)
            long = wide.melt(id_vars="pos", var_name="column", value_name="deviation_um")
            long["direction"] = np.where(long["column"].str.startswith("fwd"), "+", "-")
            long["cycle"] = long["column"].str[3:].astype(int)
            return long.drop(columns="column").rename(columns={"pos": "target"}).assign(
                machine_id=path.stem, axis="X", test_id=path.stem, method="linear")


        LAYOUT = Layout(
            name="columns", help="per-direction columns CSV",
            expected="a table with pos, fwd1.., bwd1.. columns", suffixes=(".csv",),
            reader="sitex.columns:read_columns",
            header=lambda names: "pos" in names and any(n.startswith("fwd") for n in names))
        ''',
    "plain.py": '''
        """A controller taking one backlash value per axis: ``BACKLASH <axis> = <mm>``."""

        import re

        from features.readings.fileio import write_text
        from models.physics.controller import Compensation, file_text
        from pipeline.compensation import Controller


        def write(profile, out_dir, options):
            value = profile.backlash / profile.scale
            path = write_text(out_dir / f"{profile.stem}_plain.txt",
                              f"BACKLASH {profile.axis} = {value:.4f}\\n")
            return {"files": {"parameters": path}, "interpolation_error_um": None,
                    "points": 0, "spacing_mm": None, "backlash": round(profile.backlash, 4),
                    "unconfirmed": []}


        def read(files):
            text = file_text(files["parameters"])  # a file on disk or still in memory
            value = float(re.search(r"^BACKLASH [XYZ] = (\\S+)", text, re.MULTILINE)[1])
            return Compensation(backlash_mm=value, source="plain")


        CONTROLLER = Controller(
            "plain", "Plain", ("plain-text",), write, read, kind="scalar", units="mm",
            axes=("linear",), files="text", description="one backlash value per axis",
            recognise=(("parameters", r"^BACKLASH [XYZ] ="),),
            axis_patterns=(r"^BACKLASH (?P<axis>[XYZ]) =",))
        ''',
    "mean.py": '''
        """The mean of the training targets, as a scikit-learn regressor."""

        import numpy as np
        from sklearn.base import BaseEstimator, RegressorMixin
        from sklearn.utils.validation import check_is_fitted, validate_data

        from models.serving.registry import Predictor


        class SiteMean(RegressorMixin, BaseEstimator):
            _parameter_constraints = {}

            def fit(self, X, y):
                X, y = validate_data(self, X, y)
                self.mean_ = float(np.mean(y))
                return self

            def predict(self, X):
                check_is_fitted(self)
                X = validate_data(self, X, reset=False)
                return np.full(len(X), self.mean_)


        PREDICTOR = Predictor("site-mean", "mean of the training targets (a site's own)",
                              lambda seed: SiteMean(), "json")
        ''',
    "clearance.py": '''
        """A clearance that every reversal takes up, as a site models it."""


        def site_clearance(position_mm, direction, conditions, c_um=3.0):
            """Lost motion c [um] at every reversal.

            References
            ----------
            The site's own test.
            """
            return c_um + 0.0 * position_mm


        RECORD = dict(kind="lost_motion", unit="um", amplitude="c_um", plausible=(0.0, 20.0),
                      reference="the site's own test",
                      separating_test="repeat with the indicator at the nut",
                      reading="a clearance the site measures on its own axes")
        ''',
    "spread.py": '''
        """Spread of every test's deviations [um]."""

        from dataclasses import dataclass

        from pipeline.results import Result
        from pipeline.steps.parameters import FORMAT, Param, readings
        from pipeline.steps.constraints import Interval
        from pipeline.steps.source import readings_of
        from pipeline.workflows import check_params
        from numbers import Real

        EXAMPLE = (["{twin}", "--scale", "2"], {"data": "{twin}", "scale": 2.0})
        PARAMETERS = {
            "data": readings(),
            "format": FORMAT,
            "scale": Param((Interval(Real, 0, None, closed="neither"),), "factor on the spread",
                           metavar="X"),
        }


        @dataclass
        class SpreadResult(Result):
            spread_um: dict

            def to_dict(self):
                return {"spread_um": self.spread_um}


        def site_spread(data, *, format: str = "auto", scale: float = 1.0) -> SpreadResult:
            """Spread (max - min) of every test's deviations [um], times ``scale``.

            Parameters
            ----------
            data : str, path-like or DataFrame
                Readings.
            format : str
                Layout of a readings file.
            scale : float
                Factor on the spread [-].
            """
            check_params(PARAMETERS, {"data": data, "format": format, "scale": scale},
                         "site_spread")
            readings = readings_of(data, format)
            spread = readings.groupby("test_id")["deviation_um"].agg(lambda d: d.max() - d.min())
            return SpreadResult({k: round(float(v) * scale, 6) for k, v in spread.items()})
        ''',
}
KINDS = {"formats": "columns", "controllers": "plain", "predictors": "site-mean",
         "effects": "site_clearance", "jobs": "bl.site_spread", "commands": "backlash site-spread"}


@pytest.fixture
def site(tmp_path, monkeypatch):
    """The package written to ``tmp_path``, on ``sys.path`` and registered; unregistered (and
    forgotten by the import system) afterwards, so that no other test sees it."""
    package = tmp_path / "sitex"
    package.mkdir()
    for name, text in PACKAGE.items():
        (package / name).write_text(textwrap.dedent(text))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    # A job module words its help texts from the records when it is first imported (the CLI
    # builds one command per process: the subprocess below sees the additions). Imported
    # before the additions here, so that no help text of this process keeps them afterwards.
    for record in workflows.WORKFLOWS:
        assert record.module.PARAMETERS
    before = (layouts.FORMATS, tuple(compensation.CONTROLLERS), registry.names(),
              effects.EFFECT_NAMES, workflows.NAMES)
    sitex = importlib.import_module("sitex")
    sitex.register()
    yield tmp_path
    sitex.unregister()
    for name in [m for m in sys.modules if m == "sitex" or m.startswith("sitex.")]:
        del sys.modules[name]
    assert (layouts.FORMATS, tuple(compensation.CONTROLLERS), registry.names(),
            effects.EFFECT_NAMES, workflows.NAMES) == before


def columns_file(folder: Path) -> Path:
    path = folder / "T7.csv"
    pd.DataFrame({"pos": [0.0, 50.0, 100.0], "fwd1": [0.0, 1.2, 2.1], "fwd2": [0.1, 1.3, 2.0],
                  "bwd1": [-1.9, -0.8, 0.1], "bwd2": [-2.0, -0.7, 0.2]}).to_csv(path, index=False)
    return path


def load_hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks


def test_every_kind_is_in_the_manuals_tables(site):
    hooks = load_hooks()
    for table, name in KINDS.items():
        assert f"| `{name}" in hooks.table(table), table
    page = hooks.render("# site-spread\n\n<!-- parameters -->\n", "site-spread.md")
    assert "| `scale` | `--scale` X | `1.0` | factor on the spread |" in page
    nav = hooks.on_config({"nav": [{"Jobs": [{"run (experiments)": "run.md"}]}]})["nav"]
    assert {"site-spread": "site-spread.md"} in nav[0]["Jobs"]


def test_every_kind_works_from_python(site, tmp_path):
    # the format: recognised by its header, validated like any other layout
    readings = bl.read(columns_file(tmp_path))
    assert "columns" in schema.FORMATS and len(readings) == 12
    assert set(readings["direction"]) == {"+", "-"} and readings.attrs.get("source")
    assert bl.iso(readings).figures["B"].iloc[0] > 0
    # the controller: written, read back as the controller applies it, and the twin measured
    # again with it gets better (the closed-loop check every record has)
    comp = bl.compensate(str(TWIN), controller="plain-text", verify=True, track=False)
    assert comp.controllers == ["plain"] and all(w["controller"] == "plain" for w in comp.written)
    # the predictor: trained and scored like the others
    trained = bl.train(str(TWIN), model="site-mean", track=False)
    assert trained.model == "site-mean" and np.isfinite(trained.metrics["test_rmse_um"])
    # the effect: the twin's play width sums it with the others
    x = np.array([0.0, 100.0])
    width = effects.lost_motion_um({"backlash": {"b0_um": 2.0}, "site_clearance": {}}, x, {})
    np.testing.assert_allclose(width, [5.0, 5.0])
    assert "site_clearance" in effects.LOST_MOTION
    # the job: bl.<job> through the runner, with its parameters checked
    spread = bl.site_spread(str(TWIN), scale=2.0)
    assert spread.spread_um and all(v > 0 for v in spread.spread_um.values())
    with pytest.raises(bl.InputError) as raised:
        bl.site_spread(str(TWIN), scale=-1.0)
    assert raised.value.parameter == "scale"
    assert "site_spread" in bl.__all__


def test_the_job_agrees_between_the_cli_and_python(site, tmp_path, capsys):
    """The agreement test finds the job's example in its module, as it does every job's."""
    from tests import test_runner

    (job, cli, python), = [e for e in test_runner.examples() if e[0] == "site-spread"]
    results = test_runner.both_ways(job, cli, python, {"twin": str(TWIN)}, tmp_path, capsys)
    assert results["cli"] == results["python"] and results["cli"]["spread_um"]


def test_every_kind_is_in_the_command_lines_help(site):
    """A fresh process that imports the package (as a site's start-up would) offers each
    addition in the help the commands generate from the records."""
    script = textwrap.dedent("""
        import contextlib, io, json, sys
        import sitex
        sitex.register()
        from pipeline.cli import main
        shown = {}
        for argv in (["--help"], ["convert", "--help"], ["compensate", "--help"],
                     ["train", "--help"], ["site-spread", "--help"]):
            out = io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
                main(argv)
            shown[argv[0]] = " ".join(out.getvalue().split())
        print(json.dumps(shown))
        """)
    # wide lines: argparse would wrap "site-mean" at its hyphen
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "COLUMNS": "1000"}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, cwd=site, check=False)
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)
    assert "site-spread" in shown["--help"]
    assert "columns" in shown["convert"] and "per-direction columns CSV" in shown["convert"]
    assert "csv, plain (comma-separated)" in shown["compensate"]
    assert "plain-text=plain" in shown["compensate"]
    assert "site-mean" in shown["train"]
    assert "--scale X" in shown["site-spread"]
