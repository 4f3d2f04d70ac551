"""The model registry's names: every trained predictor is logged and registered as
``backlash-predictor`` by ``pipeline.tracking.runs.log_result``, from what its result describes
(``models.serving.description.describe``: estimator parameters, history, signature, input example, the
forecasting skill and the version's tags); the best model on a data set holds the registry
alias ``champion`` (``pipeline.tracking.runs.promote_if_best``), chosen by the skill the record
carries (nothing is computed here).

Version tags (``models.serving.description.version_tags``): ``predictor``, ``target_kind``,
``data_sha256``, ``machines``, ``axes`` (``M1/X,M1/Y,...``, cut with a count), ``n_axes`` and
``backtest_skill`` (``1 - RMSE / RMSE of persistence`` over a rolling-origin backtest on the
training data, ``models.condition.backtest.forecast_skill``, or ``n/a: REASON``).
"""

from __future__ import annotations

from models.serving.description import compact_list
from pipeline.tracking.runs import (
    CHAMPION,
    CHAMPION_LOCK,
    MODEL_FIGURES,
    REGISTERED_NAME,
    REQUIREMENTS,
    promote_if_best,
)

FIGURES = MODEL_FIGURES
__all__ = ["CHAMPION", "CHAMPION_LOCK", "FIGURES", "REGISTERED_NAME", "REQUIREMENTS",
           "compact_list", "promote_if_best"]
