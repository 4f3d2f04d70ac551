"""MLflow "model from code": loads a trained model directory with ``models.serving.registry.load_model``
(exact types only, parts confined to the directory and checked against their sha256; see
``models.serving.persistence``), so nothing is unpickled and no code runs when MLflow serves or loads
the model. A broken or tampered directory raises ``InputError`` with its one-line reason.

``predict`` takes a plan (or new tests' inputs) with the columns of the model's signature
(``models.serving.signature.input_columns``) and returns a DataFrame: ``backlash_um`` and, for predictors
with an interval, ``backlash_low_um`` and ``backlash_high_um``, then ``extrapolated`` (the
inputs of each point outside the trained ranges) and, for a fleet model, ``borrowed`` (how it
forecast an axis it was not trained on): the same numbers and flags as ``backlash predict``,
from the same check (``models.serving.signature.assess``). A request it cannot interpret or may not
answer (negative operating hours, an unknown axis, a machine axis the model was not trained
on, an axis of a unit the model has no axis of) is refused as ``RefusedRequest``: ``mlflow
models serve`` answers it with HTTP 400 and a body of one line naming the row, no stack
trace.
"""

from __future__ import annotations

import json

import mlflow.pyfunc
import pandas as pd
from mlflow.exceptions import MlflowException
from mlflow.models import set_model
from mlflow.protos.databricks_pb2 import INVALID_PARAMETER_VALUE


class RefusedRequest(MlflowException):
    """A request the model refuses: HTTP 400 with the body ``{"error_code": ..., "message":
    LINE}``. The scoring server prefixes the message with the whole request frame; the body
    keeps the one line."""

    def __init__(self, line: str):
        super().__init__(line, error_code=INVALID_PARAMETER_VALUE)
        self.line = line

    def serialize_as_json(self) -> str:
        return json.dumps({"error_code": self.error_code, "message": self.line})


class BacklashPredictor(mlflow.pyfunc.PythonModel):
    def load_context(self, context):
        from models.serving.registry import load_model

        self.model = load_model(context.artifacts["model_dir"])

    def predict(self, context, model_input: pd.DataFrame, params=None) -> pd.DataFrame:
        from features.readings.errors import InputError
        from features.readings.plan import plan_points
        from models.serving.signature import prediction_frame

        try:
            points = plan_points(pd.DataFrame(model_input), "request")
            return prediction_frame(self.model, points, "request",
                                    rows=range(1, len(points) + 1))
        except InputError as err:
            raise RefusedRequest(" ".join(str(err).split())) from None


set_model(BacklashPredictor())
