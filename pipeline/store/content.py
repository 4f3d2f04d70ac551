"""The store's form of readings: one Arrow schema for every engine, one digest per test.

Every engine stores the same columns with the same types (``SCHEMA``): the contract's
columns (``docs/data-contract.md`` section 1), an optional column null where a file did not
have it, plus ``seq``, the reading's place in its test as ingested. A test's digest (SHA-256)
is taken over its readings sorted by target, direction and cycle, so it names the readings
whatever the row order or the file layout they came in; two tests with one key and different
digests contradict each other.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pyarrow as pa

from features.readings import schema
from features.readings.validation import check_readings

KEYS = list(schema.TEST_KEYS)
_TIME = pa.timestamp("us", tz="UTC")
SCHEMA = pa.schema(
    [(k, pa.string()) for k in KEYS]
    + [("seq", pa.int32()), ("method", pa.string()), ("target", pa.float64()),
       ("direction", pa.string()), ("cycle", pa.int64()), ("repeat", pa.int64()),
       ("deviation_um", pa.float64()), ("measured", pa.float64()),
       ("started_at", _TIME), ("measured_at", _TIME)]
    + [(c, pa.float64()) for c in schema.NUMERIC_OPTIONAL])
# Columns a readings frame may lack: null in the store, left out again when read back.
OPTIONAL = ("measured", "started_at", "measured_at", *schema.NUMERIC_OPTIONAL)
# The digest's version: part of every digest, so a change of definition can never match.
_DIGEST = b"backlash-store-test-v1"


def extra_columns(readings) -> list[str]:
    """Columns of ``readings`` outside the contract: the store does not keep them."""
    return [c for c in readings.columns if c not in SCHEMA.names]


def store_table(readings) -> pa.Table:
    """``readings`` (a validated frame) in the store's form, sorted by test and ``seq``."""
    codes = readings.groupby(KEYS, sort=True).ngroup().to_numpy()
    order = np.argsort(codes, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(codes[order]) != 0])
    seq = np.empty(len(order), dtype=np.int64)
    seq[order] = np.arange(len(order)) - np.repeat(starts, np.diff(np.r_[starts, len(order)]))
    columns = [pa.array(seq, pa.int32()) if f.name == "seq"
               else _arrow(readings[f.name], f.type) if f.name in readings
               else pa.nulls(len(order), f.type) for f in SCHEMA]
    return pa.table(columns, schema=SCHEMA).take(order)


def _arrow(series, type: pa.DataType) -> pa.Array:
    """One readings column as an Arrow array of the store's ``type`` (times in UTC)."""
    if pa.types.is_timestamp(type):
        naive = series.dt.tz_convert("UTC").dt.tz_localize(None).to_numpy("datetime64[us]")
        return pa.array(naive, from_pandas=True).cast(type)
    return pa.Array.from_pandas(series).cast(type, safe=False)


def digests(table: pa.Table):
    """One row per test of ``table`` (store form, sorted by test): ``KEYS``, ``sha256``,
    ``readings`` (count) and ``started_at`` (earliest, NaT when unknown)."""
    import pandas as pd

    frame = table.select([*KEYS, "method", "target", "direction", "cycle"]).to_pandas()
    keys = frame[KEYS].to_numpy()
    starts = np.flatnonzero(np.r_[True, (keys[1:] != keys[:-1]).any(axis=1)])
    ends = np.r_[starts[1:], len(frame)]
    test = np.repeat(np.arange(len(starts)), ends - starts)
    order = np.lexsort((frame["cycle"].to_numpy(), frame["direction"].to_numpy() == "-",
                        frame["target"].to_numpy(), test))
    rows = _row_bytes(table, order)
    header = frame[[*KEYS, "method"]].iloc[starts].to_numpy()
    sha = [_digest(header[i], rows[lo:hi]) for i, (lo, hi) in enumerate(zip(starts, ends))]
    started = table["started_at"].to_pandas().groupby(test).min()
    out = pd.DataFrame(header[:, :len(KEYS)], columns=KEYS)
    out["sha256"] = sha
    out["readings"] = ends - starts
    out["started_at"] = started.reset_index(drop=True)
    return out


def _digest(header, rows: np.ndarray) -> str:
    h = hashlib.sha256(_DIGEST)
    h.update("\x1f".join(header).encode("utf-8"))
    h.update(rows.tobytes())
    return h.hexdigest()


def _row_bytes(table: pa.Table, order: np.ndarray) -> np.ndarray:
    """The content of every reading as a fixed-width record (little-endian numbers, nulls
    as NaN or the smallest int64), rows in ``order``."""
    fields = [f for f in SCHEMA if f.name not in (*KEYS, "seq", "method")]
    rows = np.empty(len(order), dtype=[(f.name, "<i8" if pa.types.is_timestamp(f.type) or
                                        pa.types.is_integer(f.type) else "<f8")
                                       for f in fields if f.name != "direction"]
                    + [("direction", "i1")])
    for f in fields:
        values = _column(table, f.name)[order]
        if f.name == "direction":
            rows[f.name] = np.where(values == "-", -1, 1)
        elif pa.types.is_floating(f.type):
            rows[f.name] = np.where(np.isnan(values), np.nan, values)  # one NaN bit pattern
        else:
            rows[f.name] = values
    return rows


def _column(table: pa.Table, name: str) -> np.ndarray:
    """One column as numpy: times as int64 microseconds (null: the smallest int64), floats
    with NaN for null, text as objects."""
    column = table[name]
    if pa.types.is_timestamp(column.type):
        return column.cast(pa.int64()).fill_null(np.iinfo("i8").min).to_numpy()
    if pa.types.is_floating(column.type):
        return column.to_numpy(zero_copy_only=False).astype(float)
    if pa.types.is_string(column.type):
        return np.asarray(column.to_numpy(zero_copy_only=False), dtype=object)
    return column.to_numpy(zero_copy_only=False)


def readings_frame(table: pa.Table, source: str):
    """The validated readings frame of a store table (any row order): tests sorted by key,
    readings in their ingested order, optional columns that are null throughout left out;
    ``attrs["source"]`` is ``source``."""
    frame = table.to_pandas()
    frame = frame.sort_values([*KEYS, "seq"], ignore_index=True, kind="stable")
    drop = ["seq"] + [c for c in OPTIONAL if frame[c].isna().all()]
    ordered = [c for c in (*schema.REQUIRED, schema.DEVIATION, schema.MEASURED,
                           *schema.OPTIONAL) if c in frame and c not in drop]
    frame = frame[ordered]
    frame.attrs["source"] = source
    return check_readings(frame, "data")
