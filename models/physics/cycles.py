"""ISO 230-2 test cycles as commanded paths with overrun (ISO 230-2:2014, 3.1 and Fig. 2).

A path is a list of waypoints the motor is commanded to; readings are taken at target
waypoints after the dwell. Every test of one method and one target set shares a path, so the
axis model can run thousands of tests through it at once.

- linear: P_1 .. P_n in + direction, overrun beyond P_n, P_n .. P_1 in - direction, overrun
  below P_1; the turn-around targets (P_1 +, P_n -) follow a reversal.
- pendulum: at each target, overrun above, reverse to below, approach + and read, overrun above,
  approach - and read: every reading follows a reversal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Path:
    position_mm: np.ndarray   # commanded waypoints, the first being the start position
    read: np.ndarray          # a reading is taken at this waypoint
    target_index: np.ndarray  # index into the target list at read waypoints, else -1
    cycle: np.ndarray         # cycle 1..n at read waypoints
    direction: np.ndarray     # +1 / -1: direction of the move that reached the waypoint
    reversal: np.ndarray      # the move reaching the waypoint reverses the previous one


def target_positions(start_mm: float, stop_mm: float, n: int, irregular: bool = False,
                     seed: int = 0) -> np.ndarray:
    """n targets from start to stop; ISO irregular spacing moves each interior target by a
    random fraction (up to +-30 %) of the nominal interval so periodic errors are sampled at
    different phases (ISO 230-2:2014, 3.1.3)."""
    targets = np.linspace(start_mm, stop_mm, n)
    if irregular and n > 2:
        step = (stop_mm - start_mm) / (n - 1)
        shift = np.random.default_rng(seed).uniform(-0.3, 0.3, n - 2) * step
        targets[1:-1] += np.round(shift, 3)
    return targets


def linear_path(targets_mm, cycles: int, overrun_mm: float) -> Path:
    t = np.asarray(targets_mm, float)
    n = len(t)
    idx = np.r_[-1, np.arange(n), -1, np.arange(n)[::-1], -1]
    pos = np.r_[t[0] - overrun_mm, t, t[-1] + overrun_mm, t[::-1], t[0] - overrun_mm]
    return _assemble(t, np.tile(pos[1:], cycles), np.tile(idx[1:], cycles), cycles,
                     start=pos[0])


def pendulum_path(targets_mm, cycles: int, overrun_mm: float) -> Path:
    t = np.asarray(targets_mm, float)
    pos = np.stack([t + overrun_mm, t - overrun_mm, t, t + overrun_mm, t], axis=1).ravel()
    idx = np.stack([np.full(len(t), -1), np.full(len(t), -1), np.arange(len(t)),
                    np.full(len(t), -1), np.arange(len(t))], axis=1).ravel()
    return _assemble(t, np.tile(pos, cycles), np.tile(idx, cycles), cycles,
                     start=t[0] - 2 * overrun_mm)


def path(method: str, targets_mm, cycles: int, overrun_mm: float) -> Path:
    return (linear_path if method == "linear" else pendulum_path)(targets_mm, cycles, overrun_mm)


def _assemble(targets, pos, idx, cycles: int, start: float) -> Path:
    pos = np.r_[start, pos]
    idx = np.r_[-1, idx]
    per_cycle = (len(pos) - 1) // cycles
    cycle = np.r_[0, np.repeat(np.arange(1, cycles + 1), per_cycle)]
    step = np.diff(pos, prepend=pos[0])
    direction = np.sign(step)
    direction[0] = -1.0  # the axis arrived at the start moving down
    for k in range(1, len(direction)):  # a zero-length move keeps the previous direction
        if direction[k] == 0:
            direction[k] = direction[k - 1]
    reversal = np.r_[False, direction[1:] != direction[:-1]]
    return Path(pos, idx >= 0, idx, cycle, direction, reversal)
