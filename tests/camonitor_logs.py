"""EPICS camonitor logs of ISO 230-2 runs, written from known approach readings in the exact
format of the real ecmc logs in ``data/real/camonitor/`` (written independently of the
product's readers).

Format, as the real logs have it: ``PV date time value`` with the PV name left-justified in 30
characters, microsecond times, values followed by two spaces, PVs interleaved by time, each PV
logged only when its value changes; the encoder at 100 Hz with a few tenths of a um of noise,
the set point as a trajectory (100 Hz while moving), the test number on change only. Each
PV's first line is its value at connection, stamped with its last change before the log
started (so older than the lines above it), as camonitor does. Some reference lines carry
alarm fields (``HIGH MINOR``), as an encoder near a soft limit does.

ecmc's linear ISO 230-2 cycle: for each cycle, park below the first target, test numbers
``1cpp`` while approaching targets 1..N forward, park above the last, ``2cpp`` for targets
N..1 backward; the test number is 0 between tests. The reading of an approach is the
reference logged last before the test number changes: the writer makes that line hold the
given value exactly.
"""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path

import numpy as np

RATE_HZ = 100.0
START = dt.datetime(2021, 11, 10, 12, 0, 0)


def read_dat(path) -> tuple[dict, dict, dict]:
    """(targets {i: mm}, readings {(dir, i, j): mm}, PVs {REF_PV, TEST_PV, TGT_SET_PV}) of an
    ecmc ``*_ISO230.dat`` file (its own small parser, not the product's)."""
    targets, readings, pvs = {}, {}, {}
    for line in Path(path).read_text().splitlines():
        if m := re.fullmatch(r"TGT_DATA\[(\d+)\]=(\S+)", line.strip()):
            targets[int(m[1])] = float(m[2])
        elif m := re.fullmatch(r"REF_DATA_(FWD|BWD)\[(\d+),(\d+)\]=(\S+)", line.strip()):
            readings[(m[1], int(m[2]), int(m[3]))] = float(m[4])
        elif m := re.fullmatch(r"(REF_PV|TEST_PV|TGT_SET_PV)=(\S+)", line.strip()):
            pvs[m[1]] = m[2]
    return targets, readings, pvs


class _Log:
    def __init__(self):
        self.lines = []  # (seconds, order, text)

    def add(self, pv: str, seconds: float, value: str, alarm: str = "") -> None:
        stamp = START + dt.timedelta(seconds=round(seconds, 6))
        text = f"{pv:<30} {stamp:%Y-%m-%d %H:%M:%S.%f} {value}  {alarm}".rstrip() + "  "
        self.lines.append((seconds, len(self.lines), text))

    def text(self) -> str:
        return "\n".join(t for _, _, t in sorted(self.lines)) + "\n"


def write_run(path, targets: dict, readings: dict, pvs: dict, *, scale: float = 1.0,
              offset: float = 0.0, speed: float = 5.0, dwell: float = 2.0,
              overrun: float = 2.0, seed: int = 0, test_numbers: bool = True,
              alarms: bool = True, rate: float = RATE_HZ) -> Path:
    """Write the camonitor log of a linear ISO 230-2 run whose approach readings are
    ``readings[("FWD"|"BWD", i, j)]`` [mm, axis coordinates]; the reference PV logs
    ``(reading - offset) / scale`` (raw units), so a reader must map it back with ``scale`` and
    ``offset``. ``speed`` [mm/s], ``dwell`` [s] at each target, ``rate`` [Hz] of the encoder
    and the set point."""
    rng = np.random.default_rng(seed)
    ref_pv, test_pv, set_pv = pvs["REF_PV"], pvs["TEST_PV"], pvs["TGT_SET_PV"]
    order = sorted(targets)
    cycles = sorted({j for _, _, j in readings})
    log, t = _Log(), 1.0
    lo, hi = targets[order[0]] - overrun, targets[order[-1]] + overrun
    position = lo

    def raw(x):
        return (x - offset) / scale

    def ref(seconds, x, exact=False):
        value = raw(x) if exact else raw(x + rng.normal(0, 3e-4))
        alarm = "HIGH MINOR" if alarms and not exact and rng.random() < 0.01 else ""
        log.add(ref_pv, seconds, f"{value:.10f}" if exact else f"{value:.8f}", alarm)

    def move(to, seconds):
        nonlocal position
        steps = max(int(abs(to - position) / speed * rate), 1)
        for k in range(1, steps + 1):
            x = position + (to - position) * k / steps
            seconds += 1 / rate
            log.add(set_pv, seconds, f"{x:.6g}")
            ref(seconds + 0.002, x + rng.normal(0, 0.002))
        position = to
        return seconds

    def settle(value, seconds):
        for _ in range(int(dwell * rate) - 1):
            seconds += 1 / rate
            ref(seconds + 0.002, value + rng.normal(0, 2e-4))
        seconds += 1 / rate
        ref(seconds + 0.002, value, exact=True)  # the last reference before the change
        return seconds + 0.005

    # connection values, stamped with their last change before the log starts
    log.add(set_pv, -30.0, f"{position:.6g}")
    if test_numbers:
        log.add(test_pv, -40.0, "0")
    ref(0.01, position)
    t = move(lo, t)
    for j in cycles:
        for way, sequence, park in (("FWD", order, hi), ("BWD", order[::-1], lo)):
            for i in sequence:
                if test_numbers:
                    log.add(test_pv, t, f"{(1 if way == 'FWD' else 2) * 1000 + j * 100 + i}")
                t = move(targets[i], t + 0.05)
                t = settle(readings[(way, i, j)], t)
            if test_numbers:
                log.add(test_pv, t, "0")
            t = move(park, t + 0.05) + 0.5
    Path(path).write_text(log.text())
    return Path(path)


def run_readings(targets: dict, cycles: int, backlash_mm: float, seed: int = 0) -> dict:
    """Readings of an axis with lost motion ``backlash_mm`` (forward readings short by half,
    backward long by half: B_i = -backlash) and a little noise."""
    rng = np.random.default_rng(seed)
    return {(way, i, j): x + (-0.5 if way == "FWD" else 0.5) * backlash_mm
            + rng.normal(0, 2e-4)
            for i, x in targets.items() for j in range(1, cycles + 1) for way in ("FWD", "BWD")}


def write_trace_log(path, t_s, values: dict, digits: int = 5) -> Path:
    """A camonitor log of an axis's trace: ``values`` maps PV names to their samples at times
    ``t_s`` [s after ``START``]; each PV is logged, rounded to ``digits`` decimals, only when
    its logged value changes (a set point at rest is silent), PVs interleaved by time."""
    log = _Log()
    for pv, samples in values.items():
        text = np.char.mod(f"%.{digits}f", np.asarray(samples, float))
        changed = np.r_[True, text[1:] != text[:-1]]
        for k in np.flatnonzero(changed):
            log.add(pv, float(t_s[k]), str(text[k]))
    path = Path(path)
    path.write_text(log.text())
    return path
