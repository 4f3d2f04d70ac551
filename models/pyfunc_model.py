"""MLflow "model from code": loads a trained model directory with ``models.registry.load_model``
(exact types only, parts confined to the directory and checked against their sha256; see
``models.persistence``), so nothing is unpickled and no code runs when MLflow serves or loads
the model. A broken or tampered directory raises ``InputError`` with its one-line reason.

``predict`` takes a plan (or new tests' inputs) with the columns of the model's signature
(``models.serving.input_columns``) and returns a DataFrame: ``backlash_um`` and, for predictors
with an interval, ``backlash_low_um`` and ``backlash_high_um`` (``models.serving``), the same
numbers as ``backlash predict``."""

from __future__ import annotations

import mlflow.pyfunc
import pandas as pd
from mlflow.models import set_model


class BacklashPredictor(mlflow.pyfunc.PythonModel):
    def load_context(self, context):
        from models.registry import load_model

        self.model = load_model(context.artifacts["model_dir"])

    def predict(self, context, model_input: pd.DataFrame, params=None) -> pd.DataFrame:
        from models.serving import prediction_frame

        return prediction_frame(self.model, pd.DataFrame(model_input))


set_model(BacklashPredictor())
