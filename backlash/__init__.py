"""``import backlash as bl``: the product's public Python API under a short name.

The package layout stays ``features/``, ``models/``, ``pipeline/``; this name re-exports
``pipeline.api`` (see ``docs/api.md``).
"""

from pipeline.api import BacklashWarning, InputError, __all__, __dir__, __getattr__  # noqa: F401
