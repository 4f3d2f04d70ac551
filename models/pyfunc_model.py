"""MLflow "model from code": loads a trained model directory with ``models.registry.load_model``
(exact types only, parts confined to the directory and checked against their sha256; see
``models.persistence``), so nothing is unpickled and no code runs when MLflow serves or loads
the model. A broken or tampered directory raises ``InputError`` with its one-line reason."""

from __future__ import annotations

import mlflow.pyfunc
import pandas as pd
from mlflow.models import set_model


class BacklashPredictor(mlflow.pyfunc.PythonModel):
    def load_context(self, context):
        from models.registry import load_model

        self.model = load_model(context.artifacts["model_dir"])

    def predict(self, context, model_input: pd.DataFrame, params=None) -> list[float]:
        return [float(v) for v in self.model.predict(model_input)]


set_model(BacklashPredictor())
