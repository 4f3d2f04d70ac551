"""The product's models, in four groups and the groups of ideas beside them:

* ``models.estimators``: the predictors (the paper's shallow network, physics baselines, the
  effect model, the bootstrap ensemble) with their training, tuning and evaluation;
* ``models.physics``: the named physical effects and the feed-drive twin; ``models.machine``:
  what is identified of a machine's geometry (circular tests, volumetric errors, five-axis
  kinematics, stiffness);
* ``models.condition``: an axis's condition over time (drift and change points, the one
  maintenance analysis and its schedule, lost motion from traces, evidence beside the laser,
  backtests, monitoring of a model's inputs); ``models.wear``: the wear group;
* ``models.serving``: a trained model's registry, its one save/load protocol, its description
  and what a served model takes and gives;

and ``models.discovery`` (the missing-effect search), ``models.influence`` (which inputs drive
backlash).

A model directory saved before the modules were grouped names its classes by their old paths
(``models.network.ShallowNetwork``): ``MOVED`` maps those modules to where they live now, so
such a directory still loads (``current_name``; the import of an old path gives the module at
its new one).
"""

import importlib
import importlib.abc
import importlib.util
import sys

MOVED = {
    **{f"models.{m}": f"models.estimators.{m}" for m in (
        "network", "baselines", "effect_model", "ensemble", "training", "tuning", "evaluation")},
    **{f"models.{m}": f"models.condition.{m}" for m in (
        "drift", "monitoring", "lost_motion", "lost_motion_stream", "evidence", "backtest")},
    **{f"models.{m}": f"models.serving.{m}" for m in (
        "registry", "persistence", "pyfunc_model", "description")},
    **{f"models.{m}": f"models.machine.{m}" for m in ("circle", "volumetric")},
}
"""Old module path -> the module's path now."""


def current_name(dotted: str) -> str:
    """``dotted`` (a module or ``module.Class``) with a moved module's old path replaced by its
    path now; anything else unchanged."""
    for old, new in MOVED.items():
        if dotted == old or dotted.startswith(old + "."):
            return new + dotted[len(old):]
    return dotted


class _Moved(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old module path as the module at its path now (one module object)."""

    def find_spec(self, name, path=None, target=None):
        if name in MOVED:
            return importlib.util.spec_from_loader(name, self)
        return None

    def create_module(self, spec):
        return importlib.import_module(MOVED[spec.name])

    def exec_module(self, module):
        """Nothing to run: the module ran when imported at its path now."""


if not any(isinstance(f, _Moved) for f in sys.meta_path):
    sys.meta_path.append(_Moved())
