"""A watcher's open days in a fleet store: each machine axis's estimator state (sufficient
statistics, never samples), the days closed but not yet recorded, and its last sample time,
for ``watch`` to resume after a restart and for ``fleet`` to say when an axis went silent.

Kept beside the store's manifest as ``live/<machine>__<axis>.npz`` (plain arrays: nothing
loaded runs code), each written atomically (a temporary file, fsync, rename), so a watcher
killed at any instant leaves the previous state or the new one, never half of one.
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path

import numpy as np

from features.readings.errors import InputError

FOLDER = "live"


def live_folder(store) -> Path:
    """The store's live folder (folder stores only)."""
    root = getattr(store, "root", None)
    if root is None:
        raise InputError("watch keeps its open days in a store folder; a PostgreSQL store is "
                         "not supported yet", parameter="store")
    return Path(root) / FOLDER


def _name(machine: str, axis: str) -> str:
    return f"{machine}__{axis}.npz"


def save_state(folder: Path, machine: str, axis: str, arrays: dict, meta: dict) -> None:
    """Write one axis's state atomically."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / _name(machine, axis)
    tmp = folder / f".{path.name}.{uuid.uuid4().hex[:8]}.tmp"
    meta_bytes = np.frombuffer(json.dumps(meta, allow_nan=True).encode(), np.uint8)
    with open(tmp, "wb") as handle:
        np.savez(handle, __meta__=meta_bytes, **arrays)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def load_state(folder: Path, machine: str, axis: str):
    """(arrays, meta) of an axis's saved state, or None."""
    path = folder / _name(machine, axis)
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(bytes(arrays.pop("__meta__")).decode())
    return arrays, meta


def live_axes(store) -> list[dict]:
    """Every watched axis: machine_id, axis, last_sample (ISO, UTC), stale_after_s, source;
    ``store`` a Store or its folder."""
    # a path's own ``root`` is its anchor ("/"), not the store's folder
    root = store if isinstance(store, (str, os.PathLike)) else getattr(store, "root", None)
    if root is None or not (Path(root) / FOLDER).is_dir():
        return []
    out = []
    for path in sorted((Path(root) / FOLDER).glob("*.npz")):
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(bytes(data["__meta__"]).decode())
        except (OSError, ValueError, KeyError):
            continue
        out.extend({k: a.get(k) for k in ("machine_id", "axis", "last_sample",
                                          "stale_after_s", "source")}
                   for a in meta.get("axes", []))
    return out
