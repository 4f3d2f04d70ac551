"""CSV: everything the product knows per target, with the signs spelled out in the column names.

``deviation_*_um_measured_minus_target``: the ISO deviation means; ``correction_*_um`` = minus
that, what a controller must add to the commanded position; ``actual_*_mm`` = target +
deviation (LinuxCNC's type-0 columns); ``reversal_um_up_minus_down`` = B_i (negative for lost
motion); ``position_error_um_bidirectional`` = (up + down) / 2; ``reversal_compensation_um`` the scalar a controller adds at each reversal (not the axis's
backlash, docs/backlash.md). A rotary axis's columns say ``deg`` and ``arcsec`` instead of
``mm`` and ``um``.
"""

from __future__ import annotations

import pandas as pd

from features.readings.fileio import write_text
from pipeline.compensation.common import in_units


def write(profile, out_dir, options) -> dict:
    columns = {
        "machine_id": profile.machine_id, "axis": profile.axis, "source": profile.source,
        "target_mm": profile.target,
        "deviation_up_um_measured_minus_target": profile.mean_up,
        "deviation_down_um_measured_minus_target": profile.mean_down,
        "u_up_um": profile.u_up, "u_down_um": profile.u_down,
        "reversal_um_up_minus_down": profile.reversal,
        "position_error_um_bidirectional": profile.position_error,
        "correction_plus_um": -profile.mean_up, "correction_minus_um": -profile.mean_down,
        "actual_plus_mm": profile.target + profile.mean_up / profile.scale,
        "actual_minus_mm": profile.target + profile.mean_down / profile.scale,
        "reversal_compensation_um": profile.backlash,
    }
    frame = pd.DataFrame({in_units(name, profile): values for name, values in columns.items()})
    path = out_dir / f"{profile.stem}_compensation.csv"
    write_text(path, frame.to_csv(index=False, float_format="%.6f"))
    return {"files": {"table": path}, "interpolation_error_um": 0.0,
            "points": len(frame), "spacing_mm": None,
            "backlash": round(profile.backlash, 4), "unconfirmed": []}

