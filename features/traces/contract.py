"""Names of the trace table (docs/data-contract.md section 10): public, never rename.

A trace is what a controller logs while an axis moves: one row per sample, sorted by time
within a machine axis. Positions are in mm on a linear axis and in deg on a rotary one (the
columns keep their ``_mm`` names, as ``deviation_um`` holds arcsec on a rotary axis). After
``features.traces.io.read_trace`` a frame has every column of ``REQUIRED`` (``time`` as UTC
datetimes, ``axis`` upper-case, channels as float), ``load_mm`` and the optional channels
only when the input had them.
"""

from __future__ import annotations

TIME = "time"
REQUIRED = ("time", "machine_id", "axis", "commanded_mm", "motor_mm")
LOAD = "load_mm"  # needed for lost motion only
OPTIONAL = ("motor_current_a", "following_error_mm", "machine_temp_c")
CHANNELS = ("commanded_mm", "motor_mm", "load_mm", *OPTIONAL)
COLUMNS = (*REQUIRED, LOAD, *OPTIONAL)

# The unit each channel's name carries; a column named after a channel with another unit
# (``load_um``, ``motor_in``) is refused rather than read at the wrong scale. A rotary axis
# may name its positions in deg (``motor_deg``), which mean the same columns.
UNITS = {"commanded": "mm", "motor": "mm", "load": "mm", "following_error": "mm",
         "motor_current": "a", "machine_temp": "c"}
ROTARY_ALIAS = "deg"

# A partitioned dataset: Hive-style folders ``machine_id=M/axis=X/date=YYYY-MM-DD/*.parquet``.
PARTITION_KEYS = ("machine_id", "axis", "date")
