"""The predictors of per-point backlash and how they are fitted: the paper's shallow network
(``network``), the physics baselines (``baselines``), the effect model (``effect_model``), the
bootstrap ensemble (``ensemble``), training on a hold-out split (``training``), the Optuna
search (``tuning``) and the scores (``evaluation``)."""
