"""Renishaw ``.rtl`` laser test files (read, and write for round trips).

No public specification exists. This reader follows only what independent third-party parsers
agree on, and refuses anything else with one line:

- text (CRLF line ends; LF accepted), possibly Latin-1, in sections opened by a line ``NAME::``;
- ``TARGET DATA::`` holds ``Target-count:N`` and ``Targets :`` followed by N positions [mm],
  several per line;
- ``RUNS::`` holds ``Run-count:M``;
- ``DEVIATIONS::`` holds ``Run Target Data:`` followed by M x N lines ``run target deviation``
  (1-based run and target numbers, linear deviation [um]);
- ``USER-TEXT::`` may hold ``Machine``, ``Serial No``, ``Date``, ``Axis`` as ``key: value``;
- other sections are skipped.

Runs alternate direction in a bidirectional test: odd runs approach in the direction of the
target list (first to last target), even runs in the opposite one; cycle j is runs 2j-1 and 2j.
Readings are indexed by the target number of each line, never by row order. ``Machine``
gives ``machine_id`` (else the file name) and ``Axis`` the axis (default X); ``Serial No`` and
``Date`` are not used (the files state no date format, so a date would be a guess).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError
from features.readings.validation import finite_number

_SECTION = re.compile(r"^([A-Z][A-Z0-9 \-]*)::\s*$")


def _lines(path: Path) -> list[str]:
    try:
        data = path.read_bytes()
    except OSError as err:
        raise InputError(f"cannot read file: {err.strerror}", file=path) from None
    if b"\x00" in data:
        raise InputError("binary content; expected .rtl text", file=path)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _sections(lines: list[str], path: Path) -> dict[str, list[tuple[int, str]]]:
    sections, current = {}, None
    for row, line in enumerate(lines, start=1):
        stripped = line.strip()
        if m := _SECTION.match(stripped):
            current = m[1].strip()
            if current in sections:
                raise InputError(f"section {current}:: appears twice", file=path, row=row)
            sections[current] = []
        elif current is not None and stripped:
            sections[current].append((row, stripped))
    for name in ("TARGET DATA", "RUNS", "DEVIATIONS"):
        if name not in sections:
            raise InputError(f"missing section {name}::; expected a Renishaw .rtl file",
                             file=path)
    return sections


def _count(section: list[tuple[int, str]], key: str, name: str, path: Path) -> int:
    for row, line in section:
        if m := re.fullmatch(rf"{key}\s*:\s*(\S+)", line, flags=re.IGNORECASE):
            try:
                value = int(m[1])
            except ValueError:
                raise InputError(f"{key} {m[1]!r} is not a whole number", file=path,
                                 row=row) from None
            if value < 1:
                raise InputError(f"{key} must be at least 1, got {value}", file=path, row=row)
            return value
    raise InputError(f"section {name}:: has no {key}:", file=path)


def _targets(section: list[tuple[int, str]], path: Path) -> np.ndarray:
    n = _count(section, "Target-count", "TARGET DATA", path)
    start = next((i for i, (_, line) in enumerate(section)
                  if re.match(r"Targets\s*:", line, flags=re.IGNORECASE)), None)
    if start is None:
        raise InputError("section TARGET DATA:: has no 'Targets :' line", file=path)
    values = []
    first_row, first = section[start]
    rest = first.split(":", 1)[1]
    for row, line in [(first_row, rest), *section[start + 1:]]:
        if len(values) == n:
            break
        tokens = line.replace(",", " ").split()
        if len(values) + len(tokens) > n:
            raise InputError(f"more than Target-count {n} target positions", file=path, row=row)
        values += [finite_number(token, path, row, "target position") for token in tokens]
    if len(values) != n:
        raise InputError(f"{len(values)} target positions; Target-count says {n}", file=path)
    targets = np.asarray(values)
    if len(np.unique(targets)) != n:
        raise InputError("target positions repeat; expected N distinct positions", file=path)
    return targets


def _deviations(section: list[tuple[int, str]], runs: int, n: int, path: Path) -> np.ndarray:
    start = next((i for i, (_, line) in enumerate(section)
                  if re.fullmatch(r"Run Target Data\s*:", line, flags=re.IGNORECASE)), None)
    if start is None:
        raise InputError("section DEVIATIONS:: has no 'Run Target Data:' line", file=path)
    grid = np.full((runs, n), np.nan)
    for row, line in section[start + 1:]:
        parts = line.split()
        if len(parts) != 3:
            raise InputError(f"expected 'run target deviation', got {line!r}", file=path, row=row)
        run, target = (_index(p, limit, path, row, what) for p, limit, what in
                       ((parts[0], runs, "run"), (parts[1], n, "target")))
        if not np.isnan(grid[run - 1, target - 1]):
            raise InputError(f"run {run} target {target} appears twice", file=path, row=row)
        grid[run - 1, target - 1] = finite_number(parts[2], path, row, "deviation")
    missing = np.argwhere(np.isnan(grid))
    if len(missing):
        run, target = missing[0] + 1
        raise InputError(f"no deviation for run {run} target {target}; expected "
                         f"{runs} x {n} lines", file=path)
    return grid


def _index(text: str, limit: int, path: Path, row: int, what: str) -> int:
    if not re.fullmatch(r"\d+", text) or not 1 <= int(text) <= limit:
        raise InputError(f"{what} {text!r}: expected a number from 1 to {limit}", file=path,
                         row=row)
    return int(text)


def _user_text(section: list[tuple[int, str]]) -> dict[str, str]:
    out = {}
    for _, line in section:
        if ":" in line:
            key, value = (p.strip() for p in line.split(":", 1))
            out[key.lower()] = value
    return out


def read_rtl(path) -> pd.DataFrame:
    """Long readings (not yet validated) from a bidirectional ``.rtl`` linear test."""
    path = Path(path)
    sections = _sections(_lines(path), path)
    targets = _targets(sections["TARGET DATA"], path)
    runs = _count(sections["RUNS"], "Run-count", "RUNS", path)
    if runs % 2:
        raise InputError(f"Run-count {runs} is odd; a bidirectional test has runs in pairs",
                         file=path)
    grid = _deviations(sections["DEVIATIONS"], runs, len(targets), path)
    user = _user_text(sections.get("USER-TEXT", []))
    axis = user.get("axis", "X").strip().upper() or "X"
    machine = user.get("machine", "").strip() or path.stem
    forward = "+" if targets[-1] > targets[0] else "-"
    backward = "-" if forward == "+" else "+"
    run = np.repeat(np.arange(1, runs + 1), len(targets))
    frame = pd.DataFrame({
        "machine_id": machine, "axis": axis, "test_id": path.stem, "method": "linear",
        "target": np.tile(targets, runs),
        "direction": np.where(run % 2 == 1, forward, backward),
        "cycle": (run + 1) // 2, "deviation_um": grid.ravel(),
    })
    frame.attrs[schema.UNSTATED] = tuple(
        column for column, key in (("machine_id", "machine"), ("axis", "axis"))
        if not user.get(key, "").strip())
    return frame


def write_rtl(readings: pd.DataFrame, path) -> Path:
    """One bidirectional linear test as ``.rtl`` (CRLF), runs 2j-1 (+) and 2j (-) per cycle."""
    from features.readings.fileio import atomic_path

    tests = readings[["machine_id", "axis", "test_id"]].drop_duplicates()
    if len(tests) != 1:
        raise InputError(f"an .rtl file holds one test; got {len(tests)}", file=path)
    targets = np.sort(readings["target"].unique())
    cycles = np.sort(readings["cycle"].unique())
    by = readings.set_index(["cycle", "direction", "target"])["deviation_um"]
    if by.index.duplicated().any():
        raise InputError("duplicate readings (cycle, direction, target)", file=path)
    lines = ["USER-TEXT::", f"Machine: {tests['machine_id'].iloc[0]}",
             f"Axis: {tests['axis'].iloc[0]}", "", "TARGET DATA::",
             f"Target-count:{len(targets)}", "Targets :"]
    lines += [" ".join(f"{t:.6f}" for t in targets[i:i + 5]) for i in range(0, len(targets), 5)]
    lines += ["", "RUNS::", f"Run-count:{2 * len(cycles)}", "", "DEVIATIONS::",
              "Run Target Data:"]
    for j, cycle in enumerate(cycles):
        for offset, direction in ((1, "+"), (2, "-")):
            order = range(len(targets)) if direction == "+" else reversed(range(len(targets)))
            for i in order:
                value = by.get((cycle, direction, targets[i]))
                if value is None:
                    raise InputError(f"no reading at cycle {cycle} direction {direction} target "
                                     f"{targets[i]:g}", file=path)
                lines.append(f"{2 * j + offset} {i + 1} {value:.6f}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1", "replace"))
    return Path(path)
