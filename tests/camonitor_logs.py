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

ecmc's linear ISO 230-2 cycle, as ecmc's test scripts run it and its extraction
(``ecmcGetISO230DataFromCAFile.bash``, ``ecmcGetDataBeforeTrigg.bash``) reads it: for each
cycle, park below the first target, approach targets 1..N forward, park above the last,
approach N..1 backward. The test number ``d c 0 p`` (1101: forward, cycle 1, position 1) is
set once the axis has settled at the target, then the axis moves on: the reading of an
approach is the reference logged last, in the file's order, before the line where the test
number takes its value, and the writer makes that line hold the given value exactly. The
test number is a soft PV stamped by the host a few milliseconds after the controller's
cycle, so the first samples of the next move, stamped by the controller, follow it in the
file with earlier times (a reader sorting by time takes a sample of the move). After the
run the axis may move again while the set point still holds the last target (ecmc's
resolver test, ``tail_mm``).
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
        self.lines = []  # (file position, order, text)

    def add(self, pv: str, seconds: float, value: str, alarm: str = "",
            stamp: float | None = None) -> None:
        """A line at file position ``seconds``, stamped ``stamp`` (default ``seconds``)."""
        when = START + dt.timedelta(seconds=round(seconds if stamp is None else stamp, 6))
        text = f"{pv:<30} {when:%Y-%m-%d %H:%M:%S.%f} {value}  {alarm}".rstrip() + "  "
        self.lines.append((seconds, len(self.lines), text))

    def text(self) -> str:
        return "\n".join(t for _, _, t in sorted(self.lines)) + "\n"


# The host stamps the test number this long after the controller's cycle it follows [s].
HOST_DELAY_S = 0.006


def write_run(path, targets: dict, readings: dict, pvs: dict, *, scale: float = 1.0,
              offset: float = 0.0, speed: float = 5.0, dwell: float = 2.0,
              overrun: float = 2.0, seed: int = 0, test_numbers: bool = True,
              alarms: bool = True, rate: float = RATE_HZ, tail_mm: float = 0.0,
              invalid: int = 0, motor_pv: str | None = None) -> Path:
    """Write the camonitor log of a linear ISO 230-2 run whose approach readings are
    ``readings[("FWD"|"BWD", i, j)]`` [mm, axis coordinates]; the reference PV logs
    ``(reading - offset) / scale`` (raw units), so a reader must map it back with ``scale`` and
    ``offset``. ``speed`` [mm/s], ``dwell`` [s] at each target, ``rate`` [Hz] of the encoder
    and the set point; ``tail_mm``: after the last approach the axis moves this far and back
    with the set point held (ecmc's resolver test); ``invalid``: this many reference samples
    during the dwells are dropouts logged with severity INVALID and a wild value;
    ``motor_pv``: an open-loop step counter, at the set point (and moving in the tail).

    The load follows the motor with its play taken up: while the axis moves towards a target
    the reference reads the set point plus that approach's deviation (reading - target), so a
    reversal shifts it by the lost motion, as a real axis does."""
    rng = np.random.default_rng(seed)
    ref_pv, test_pv, set_pv = pvs["REF_PV"], pvs["TEST_PV"], pvs["TGT_SET_PV"]
    order = sorted(targets)
    cycles = sorted({j for _, _, j in readings})
    width_p, width_c = len(str(max(order))), len(str(max(cycles)))
    log = _Log()
    lo, hi = targets[order[0]] - overrun, targets[order[-1]] + overrun
    position = lo
    dropouts = set(rng.choice(len(readings) * int(dwell * rate), invalid, replace=False)
                   if invalid else [])
    settled = 0

    def raw(x):
        return (x - offset) / scale

    def ref(seconds, x, exact=False):
        value = raw(x) if exact else raw(x + rng.normal(0, 3e-4))
        alarm = "HIGH MINOR" if alarms and not exact and rng.random() < 0.01 else ""
        log.add(ref_pv, seconds, f"{value:.10f}" if exact else f"{value:.8f}", alarm)

    def move(to, seconds, shift=0.0):
        """The first step in the cycle ``seconds`` (right after a test number), then one per
        sample; the load ``shift`` [mm] from the set point; returns the time of the last."""
        nonlocal position
        steps = max(int(abs(to - position) / speed * rate), 1)
        for k in range(1, steps + 1):
            x = position + (to - position) * k / steps
            log.add(set_pv, seconds, f"{x:.6g}")
            if motor_pv:
                log.add(motor_pv, seconds + 0.001, f"{x:.6g}")
            ref(seconds + 0.002, x + shift + rng.normal(0, 2e-4))
            seconds += 1 / rate
        position = to
        return seconds - 1 / rate

    def settle(value, seconds):
        nonlocal settled
        for _ in range(int(dwell * rate) - 1):
            seconds += 1 / rate
            if settled in dropouts:  # a lost frame: the record holds no measurement
                log.add(ref_pv, seconds + 0.002, f"{raw(value) * 1e3 + 7.7:.8f}", "READ INVALID")
            else:
                ref(seconds + 0.002, value + rng.normal(0, 2e-4))
            settled += 1
        seconds += 1 / rate
        ref(seconds + 0.002, value, exact=True)  # the last reference before the test number
        return seconds + 1 / rate

    # connection values, stamped with their last change before the log starts
    log.add(set_pv, -30.0, f"{position:.6g}")
    if motor_pv:
        log.add(motor_pv, -30.0, f"{position:.6g}")
    if test_numbers:
        log.add(test_pv, -40.0, "0")
    ref(0.01, position)
    t = move(lo, 1.0) + 0.5
    last, shift = (cycles[-1], "BWD"), 0.0
    for j in cycles:
        for way, sequence, park in (("FWD", order, hi), ("BWD", order[::-1], lo)):
            for i in sequence:
                shift = readings[(way, i, j)] - targets[i]  # the play, taken up this way
                t = move(targets[i], t, shift)
                t = settle(readings[(way, i, j)], t)
                if test_numbers:
                    code = f"{1 if way == 'FWD' else 2}{j:0{width_c}d}0{i:0{width_p}d}"
                    log.add(test_pv, t, code, stamp=t + HOST_DELAY_S)
            if (j, way) != last or not tail_mm:
                t = move(park, t, shift) + 0.5
    if tail_mm:  # the axis moves with the set point held: no stop, no reading
        here = readings[("BWD", order[0], cycles[-1])]
        for k in range(1, int(4 * rate)):
            x = here + tail_mm * np.sin(np.pi * k / (4 * rate))
            if motor_pv:
                log.add(motor_pv, t + k / rate + 0.001, f"{x - shift:.6g}")
            ref(t + k / rate + 0.002, x)
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
