"""Inputs and their physical paths to lost motion, read from the effect records."""

from __future__ import annotations

from dataclasses import dataclass

# Inputs the backlash target is computed from: they carry its measurement noise.
TARGET_DERIVED = ("deviation_down_um", "deviation_up_um")
WEAR = "operating_hours"
WEAR_READING = ("wear of screw and nut with running time since the last adjustment opens the "
                "clearance")
LABELS = {
    "target": "Position", "deviation_down_um": "Negative-direction deviation",
    "deviation_up_um": "Positive-direction deviation", "feed_mm_min": "Feed rate",
    "machine_temp_c": "Machine temperature", "ambient_temp_c": "Ambient temperature",
    "pressure_hpa": "Atmospheric pressure", "humidity_pct": "Air humidity",
    "dwell_s": "Dwell time", "operating_hours": "Operating hours",
}


@dataclass(frozen=True)
class Path:
    """How an input can act: effects on lost motion (``paths``) and on the measured position
    only (``position``), each with its physical reading."""

    paths: tuple[tuple[str, str], ...]      # (effect name, reading)
    position: tuple[tuple[str, str], ...]   # (effect name, reading)


def effect_paths(inputs) -> dict[str, Path]:
    """Per input: the lost-motion effects that read it (a physical path to backlash) and the
    position effects that read it (a path to the measured position only).

    Source: ``models.physics.effects.EFFECTS`` (``kind``, ``inputs``, ``reading``). Operating
    hours act through wear of screw and nut (the twin's ``wear_um_per_1000h``) unless a record
    already lists them.
    """
    found = {name: ([], []) for name in inputs}
    for name, kind, needs, reading in _records():
        reading = reading.strip().rstrip(".")
        for used in needs:
            if used in found:
                found[used][0 if kind == "lost_motion" else 1].append((name, reading))
    if WEAR in found and not found[WEAR][0]:
        found[WEAR][0].append(("wear", WEAR_READING))
    return {k: Path(tuple(lost), tuple(pos)) for k, (lost, pos) in found.items()}


def _records():
    """(name, kind, inputs, reading) of every effect record."""
    from models.physics.effects import EFFECTS

    return [(r.name, r.kind, tuple(r.inputs), r.reading) for r in EFFECTS.values()]

