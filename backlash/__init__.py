"""``import backlash as bl``: the product's public Python API under a short name.

The package layout stays ``features/``, ``models/``, ``pipeline/``; this name re-exports
``pipeline.api`` (see ``docs/api.md``).
"""

# ``__all__`` and every job's name come from ``pipeline.api.__getattr__``: read from the job
# records when asked, so a job added by ``pipeline.workflows.register`` is ``bl.<job>`` too.
from pipeline.api import BacklashWarning, InputError, __dir__, __getattr__  # noqa: F401
