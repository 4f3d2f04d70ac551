"""A trained predictor as it is kept and served: the named predictors and a model directory
(``registry``), the one save/load protocol (``persistence``), what is known of it
(``description``), the MLflow model from code (``pyfunc_model``) and what a served model takes
and gives (``signature``)."""
