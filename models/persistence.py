"""One save/load protocol for every fitted estimator and every part of a composite one.

An estimator is stored either by its own ``save``/``load`` (torch state dicts, JSON
coefficients) or as a skops file. Loading never unpickles: skops files are checked against
the trusted types before anything is constructed, and classes that load themselves must
live in this project's ``models`` package. The spec returned by ``save_estimator`` is what
``load_estimator`` needs back; callers keep it in their own JSON.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from features.readings.errors import InputError
from features.readings.fileio import atomic_path

TRUSTED_PREFIXES = ("sklearn.", "numpy.", "scipy.", "models.", "builtins.", "collections.")


def save_estimator(estimator, directory, name: str) -> dict:
    """Write ``estimator`` into ``directory`` under ``name``; return its spec
    (``format`` 'self' or 'skops', ``class``, ``path`` relative to ``directory``)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    cls = f"{type(estimator).__module__}.{type(estimator).__qualname__}"
    if hasattr(estimator, "save"):
        estimator.save(directory / name)
        return {"format": "self", "class": cls, "path": name}
    import skops.io

    with atomic_path(directory / f"{name}.skops") as tmp:
        skops.io.dump(estimator, tmp)
    return {"format": "skops", "class": cls, "path": f"{name}.skops"}


def load_estimator(directory, spec: dict, where=None):
    """Read back what ``save_estimator`` wrote; ``where`` names the file in errors."""
    path = Path(directory) / spec["path"]
    if spec["format"] == "skops":
        return load_skops(path)
    module, _, cls = spec["class"].rpartition(".")
    if not module.startswith("models."):
        raise InputError(f"refusing estimator class {spec['class']!r}", file=where or path)
    return getattr(importlib.import_module(module), cls).load(path)


def load_skops(path: Path):
    import skops.io

    if not path.is_file():
        raise InputError("model directory has no estimator file", file=path)
    untrusted = skops.io.get_untrusted_types(file=path)
    refused = [t for t in untrusted if not t.startswith(TRUSTED_PREFIXES)]
    if refused:
        raise InputError(f"refusing to load type {refused[0]!r} from an untrusted model file",
                         file=path)
    return skops.io.load(path, trusted=untrusted)
