"""Tracking: MLflow runs and Optuna studies (``runs``: the one place that decides where runs,
models, artifacts and studies go, and the one adapter from a result to MLflow), the model
registry and its champion (``model_registry``), and the forked child a command hands its run to
(``background``).

This package's own module is light: the CLI reads ``TRACKING_DIR`` and the program allows the
background child (``allow_fork``) on every start, which must not load the tracking code.
"""

TRACKING_DIR = "BACKLASH_TRACKING_DIR"  # the tracking folder (the CLI's --tracking-dir)
_fork = {"allowed": False}  # set by the ``backlash`` program; library callers and tests stay


def allow_fork() -> None:
    """Let runs started from now on use a child process (``background``); only the
    ``backlash`` program calls it (``pipeline.cli.program``): a library caller's process is
    not ours to fork."""
    _fork["allowed"] = True


def fork_allowed() -> bool:
    return _fork["allowed"]
