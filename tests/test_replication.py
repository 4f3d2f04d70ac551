"""The paper's replication is two modules: the numbers (``pipeline.replication.fitting``) and
their figures and written report (``pipeline.replication.plotting``); the package gives both
under the names it always had. The full replication on a twin is in tests/test_ranking.py."""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

import numpy as np

from pipeline import replication
from pipeline.replication import fitting, plotting

NUMBERS = ("DEVIATIONS", "PAPER", "PAPER_TABLE5", "comparison_rows", "network_run", "replicate")
OUTPUT = ("FILES", "markdown", "plot_fig10", "plot_fig13", "write_replication")


def test_the_package_gives_every_public_name_of_both_modules():
    for module, names in ((fitting, NUMBERS), (plotting, OUTPUT)):
        for name in names:
            assert getattr(replication, name) is getattr(module, name), name
        public = {n for n, v in vars(module).items() if not n.startswith("_")
                  and getattr(v, "__module__", module.__name__) == module.__name__
                  and not isinstance(v, type(sys))}
        public -= {"annotations"} | (set(NUMBERS) if module is plotting else set())
        assert public <= set(names), public - set(names)
    assert sorted(replication.__all__) == sorted(NUMBERS + OUTPUT)


def test_fitting_draws_nothing():
    """The numbers import neither matplotlib nor the report page nor the plotting module,
    not even inside a function."""
    tree = ast.parse(Path(fitting.__file__).read_text(encoding="utf-8"))
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names}
    imported |= {node.module for node in ast.walk(tree)
                 if isinstance(node, ast.ImportFrom) and node.module}
    drawing = {name for name in imported
               if name.startswith(("matplotlib", "pipeline.reports", "pipeline.replication"))}
    assert not drawing, drawing


def _case(columns, rng, n=30):
    target = rng.normal(5, 1, n)
    parts = {"training": np.arange(0, 20), "validation": np.arange(20, 25),
             "test": np.arange(25, n), "all": np.arange(n)}
    history = {k: list(np.linspace(1, 0.1, 8)) for k in ("train_mse", "val_mse", "test_mse")}
    return {
        "network": {"best_epoch": 5, "epochs": 7, "stop_reason": "validation",
                    "regression_r": dict.fromkeys(parts, 0.9), "history": history,
                    "target": target, "output": target + rng.normal(0, 0.1, n),
                    "parts": parts},
        "knn_accuracy": 0.8, "knn_accuracy_std": 0.05, "knn_majority_rate": 0.25,
        "knn_ceiling": float("nan"),
        "anova": {c: float(i) for i, c in enumerate(columns)},
        "anova_order": list(columns),
        "verdict": {c: "driver" if c == "target" else "proxy" if c in fitting.DEVIATIONS
                    else "none" for c in columns},
        "proxy_for": {c: "target" if c in fitting.DEVIATIONS else "" for c in columns},
    }


def test_plotting_writes_every_file_from_the_numbers_alone(tmp_path):
    rng = np.random.default_rng(0)
    columns = list(fitting.PAPER_TABLE5)
    results = {"with deviations": _case(columns, rng),
               "without deviations": _case([c for c in columns
                                            if c not in fitting.DEVIATIONS], rng)}
    paths = plotting.write_replication(results, tmp_path, source="twin.csv")
    assert set(paths) == set(plotting.FILES)
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths.values())
    rows = fitting.comparison_rows(results)
    assert paths["md"].read_text(encoding="utf-8") == plotting.markdown(rows)
    assert json.loads(paths["json"].read_text(encoding="utf-8"))["table"] == rows
    assert "twin.csv" in paths["html"].read_text(encoding="utf-8")
