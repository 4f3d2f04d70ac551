"""The model jobs' options (train, predict, compare, tune, rank, replicate) come from their
parameter tables: what the command line parses reaches the workflow as Python would give it,
with the workflow's own defaults, and a bad value is one line naming the option."""

from __future__ import annotations

import inspect

import pytest
from test_cli_errors import refused, small_table

from pipeline.cli import build_parser
from pipeline.commands.data import given
from pipeline.workflows import workflow

JOBS = ("train", "predict", "compare", "tune", "rank", "replicate")


def parsed(argv: list[str]) -> dict:
    """The job's parameters as ``run_job`` hands them to the runner."""
    args = build_parser(argv).parse_args(argv)
    return given(argv[0], args)


@pytest.mark.parametrize("job", JOBS)
def test_every_option_defaults_to_the_workflows_default(job):
    argv = {"predict": [job, "model/", "data.csv", "--out", "p.csv"],
            "tune": [job, "data.csv"]}.get(job, [job, "data.csv", "--out", "out/"])
    params = parsed(argv)
    signature = inspect.signature(workflow(job).function).parameters
    for name, value in params.items():
        if name in signature and name not in ("data", "model"):
            assert value == signature[name].default, (job, name)
    assert params["data"] == "data.csv"


def test_comma_lists_reach_the_workflow_as_lists():
    assert parsed(["train", "d.csv", "--out", "m", "--features", "feed_mm_min, target"])[
        "features"] == ["feed_mm_min", "target"]
    compare = parsed(["compare", "d.csv", "--models", "constant,ridge", "--split", "backtest"])
    assert compare["models"] == ["constant", "ridge"] and compare["split"] == "backtest"
    assert parsed(["predict", "model/", "d.csv", "--out", "p.csv"])["model"] == "model/"


def test_rank_keeps_its_bins_text_and_its_drop_column_switch():
    ranked = parsed(["rank", "d.csv", "--out", "r", "--bins", "2,4.5", "--no-dropcolumn"])
    assert ranked["bins"] == "2,4.5" and ranked["dropcolumn"] is False
    assert parsed(["rank", "d.csv", "--out", "r"])["dropcolumn"] is True


def test_tune_has_no_hold_out_options():
    """tune cross-validates: a hold-out split or a truth table would be ignored, so the
    command line offers neither (the workflow takes neither)."""
    with pytest.raises(SystemExit):
        build_parser(["tune"]).parse_args(["tune", "d.csv", "--split", "forward"])


@pytest.mark.parametrize("argv, words", [
    (["train", "{data}", "--out", "{tmp}/m", "--features", " , "], "--features: is empty"),
    (["train", "{data}", "--out", "{tmp}/m", "--seed", "-1"],
     "--seed: '-1': expected an int in the range [0, 4294967295]"),
    (["compare", "{data}", "--models", ","], "--models: is empty"),
    (["compare", "{data}", "--split", "sideways"], "invalid choice: 'sideways'"),
    (["tune", "{data}", "--folds", "1"], "'1': expected an int in the range [2, inf)"),
    (["replicate", "{data}", "--out", "{tmp}/r", "--boot", "-1"],
     "'-1': expected an int in the range [0, inf)"),
    (["rank", "{data}", "--out", "{tmp}/r", "--bins", "1"], "--bins: must be at least 2"),
    (["predict", "{tmp}/m", "{data}", "--out", "{tmp}/p.txt"], "expected a .csv file name"),
    (["predict", "{data}", "--out", "{tmp}/p.csv"], "required: DATA"),
])
def test_bad_model_option_is_one_line_and_writes_nothing(tmp_path, capsys, argv, words):
    data = small_table(tmp_path)
    line = refused(capsys, [a.format(data=data, tmp=tmp_path / "o") for a in argv])
    assert words in line
    assert not (tmp_path / "o").exists()
