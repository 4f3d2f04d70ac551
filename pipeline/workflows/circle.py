"""Circular tests (ISO 230-4): the circular deviation G of each run, the circular hysteresis H
and the diagnosis of what made the path depart from the circle.

>>> import backlash as bl
>>> result = bl.circle("experiments/data/circle/ballbar_xy.csv")          # doctest: +SKIP
>>> result.circles[0].diagnosis.value["backlash_1"]                       # doctest: +SKIP
4.7...

A circle is one machine, plane, visit, radius and feed with a CW and a CCW run
(``features.circle``). The diagnosis fits both runs at once with the error signatures of
``models.machine.circle``: each axis's play (the step where it reverses) and reversal spike,
out-of-squareness, scale mismatch and servo mismatch, each with its standard uncertainty.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from pipeline.results import Result
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import Param

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{circle}"],
    {"data": "{circle}"},
)

PARAMETERS = {
    "data": Param((str, os.PathLike, "pandas.DataFrame"), flag="FILE"),
    "out": Param((str, os.PathLike, None), "output folder: a polar plot per circle, "
                 "circles.csv, circles.html", metavar="DIR", output="folder"),
    "tolerance_um": Param((None, Interval(Real, 0, None, closed="neither")),
                          flag="--tolerance", metavar="UM"),
    "store": Param((str, os.PathLike, None), "fleet store (folder or postgresql:// URL; "
                   "docs/fleet.md) to record each diagnosed circle's backlash in: one ballbar "
                   "record per axis of its plane, dated by the earliest started_at of its runs; "
                   "the same circles again add nothing", metavar="STORE"),
}

# JSON keys of the diagnosis: (key, model term of the first axis, of the second) or (key, term).
AXIS_KEYS = (("backlash_um", "backlash_1", "backlash_2"),
             ("reversal_spike_um", "spike_1", "spike_2"))
PLANE_KEYS = (("squareness_um_per_m", "squareness"), ("scale_mismatch_ppm", "scale"),
              ("servo_mismatch_ms", "servo"))
SUMMARY = {"csv": "circles.csv", "html": "circles.html"}


@dataclass
class CircleFigures:
    """One circular test evaluated.

    Attributes
    ----------
    circle : features.circle.Circle
        The test as read.
    G_um : dict of str to float or None
        ISO 230-4 circular deviation of each run [um] (None for a missing direction).
    H_um : float or None
        Circular hysteresis [um]; None without both directions.
    diagnosis : models.machine.circle.Diagnosis or None
        The effects fitted; None without both directions.
    """

    circle: object  # features.circle.Circle
    G_um: dict
    H_um: float | None
    diagnosis: object  # models.machine.circle.Diagnosis or None

    def diagnosis_json(self) -> dict | None:
        """The diagnosis as SCHEMA.md section 11 names it, keys by the plane's axes, with
        ``uncertainty`` (standard, k = 1) of the same shape."""
        if self.diagnosis is None:
            return None
        first, second = self.circle.axes

        def shaped(values: dict) -> dict:
            out = {key: {first: values[a], second: values[b]} for key, a, b in AXIS_KEYS}
            out.update({key: values[term] for key, term in PLANE_KEYS})
            return out

        return {**shaped(self.diagnosis.value), "uncertainty": shaped(self.diagnosis.u),
                "rms_residual_um": self.diagnosis.rms_residual_um}

    def diagnosis_lines(self) -> list[tuple[str, float, float]]:
        """(label, value, standard uncertainty) of every effect, for tables and the plot."""
        first, second = self.circle.axes
        d = self.diagnosis
        lines = []
        for key, a, b in AXIS_KEYS:
            name = "backlash" if key == "backlash_um" else "spike"
            lines += [(f"{name} {first} [um]", d.value[a], d.u[a]),
                      (f"{name} {second} [um]", d.value[b], d.u[b])]
        labels = {"squareness": "squareness [um/m]", "scale": "scale [ppm]",
                  "servo": "servo [ms]"}
        lines += [(labels[t], d.value[t], d.u[t]) for _, t in PLANE_KEYS]
        return lines

    def summary(self) -> dict:
        """One row of ``circles.csv``."""
        from features import circle as fc

        c = self.circle
        row = {"machine_id": c.machine_id, "plane": c.plane, "visit": c.visit,
               "radius_mm": c.radius_mm, "feed_mm_min": c.feed_mm_min,
               **{f"G_{d}_um": self.G_um.get(d) for d in fc.DIRECTIONS}, "H_um": self.H_um}
        if self.diagnosis is not None:
            first, second = c.axes
            for key, a, b in AXIS_KEYS:
                stem = key.removesuffix("_um")
                for axis, term in ((first, a), (second, b)):
                    row[f"{stem}_{axis}_um"] = self.diagnosis.value[term]
                    row[f"{stem}_{axis}_u_um"] = self.diagnosis.u[term]
            for key, term in PLANE_KEYS:
                row[key] = self.diagnosis.value[term]
                row[f"{key}_u"] = self.diagnosis.u[term]
        return row


@dataclass
class CircleResult(Result):
    """Circular tests evaluated: ``circles`` in the order of the file.

    Attributes
    ----------
    circles : list of CircleFigures
    source : str
        The file the tests came from.
    tolerance_um : float or None
        The tolerance band drawn in the plots [um].
    dates : dict or None
        The day (ISO, UTC) of each circle, (machine, plane, visit, radius, feed) -> the
        earliest ``started_at`` of its runs: what dates its backlash in a fleet store
        (``pipeline.store.records.record_ballbar``); None when a run has no ``started_at``.
    recorded : pipeline.store.records.Recorded or None
        What ``store`` recorded (the runner sets it).
    """

    circles: list
    source: str = ""
    tolerance_um: float | None = None
    parameters: dict = field(default_factory=dict)
    dates: dict | None = field(default=None, repr=False)
    recorded: object = None

    def to_dict(self) -> dict:
        """``{"circles": [...]}`` as SCHEMA.md section 11 names it; NaN becomes None."""
        from features.readings.fileio import clean_nan

        items = []
        for item in self.circles:
            c = item.circle
            items.append({"machine_id": c.machine_id, "plane": c.plane, "visit": c.visit,
                          "radius_mm": c.radius_mm, "feed_mm_min": c.feed_mm_min,
                          "test_ids": {d: r.test_id for d, r in c.runs.items()},
                          "G_um": item.G_um, "H_um": item.H_um,
                          "diagnosis": item.diagnosis_json()})
        return clean_nan({"source": self.source, "circles": items, "notes": list(self.notes)})

    def table(self) -> str:
        """Three lines per circle: G and H; backlash and spike per axis; the plane's effects
        (each value ± its standard uncertainty)."""
        lines = []
        for item in self.circles:
            c = item.circle
            g = ", ".join(f"G {d} {v:.2f}" for d, v in item.G_um.items() if v is not None)
            h = f", H {item.H_um:.2f}" if item.H_um is not None else ""
            lines.append(f"{c.machine_id} {c.plane} visit {c.visit} R {c.radius_mm:g} mm "
                         f"F {c.feed_mm_min:g} mm/min: {g}{h} um")
            d = item.diagnosis
            if d is None:
                continue
            axes = [f"{name} " + "  ".join(f"{axis} {d.value[t]:.2f} ± {d.u[t]:.2f}"
                                            for axis, t in zip(c.axes, terms)) + " um"
                    for name, *terms in (("backlash", "backlash_1", "backlash_2"),
                                         ("reversal spike", "spike_1", "spike_2"))]
            lines.append("  " + "; ".join(axes))
            lines.append("  " + "; ".join(
                f"{name} {d.value[t]:.2f} ± {d.u[t]:.2f} {unit}" for name, t, unit in (
                    ("squareness", "squareness", "um/m"), ("scale mismatch", "scale", "ppm"),
                    ("servo mismatch", "servo", "ms"))))
        return "\n".join(lines)

    def write(self, out) -> dict[str, Path]:
        """Under ``out``: a polar plot per circle (``circle_<machine>_<plane>_<visit>.png``),
        ``circles.csv`` (one row per circle) and ``circles.html`` (the table and the plots)."""
        import pandas as pd

        from features.readings.fileio import atomic_path
        from pipeline.reports.circle_chart import plot_circle
        from pipeline.reports.report_page import write_page

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        pngs = []
        for item, name in zip(self.circles, plot_names(self.circles)):
            pngs.append(plot_circle(item, out / name, self.tolerance_um))
            self.files[f"plot {name}"] = pngs[-1]
        with atomic_path(out / SUMMARY["csv"]) as tmp:
            pd.DataFrame([i.summary() for i in self.circles]).to_csv(tmp, index=False)
        self.files["csv"] = out / SUMMARY["csv"]
        self.files["html"] = write_page(out / SUMMARY["html"], "Circular tests (ISO 230-4)",
                                        self._html(pngs))
        return self.files

    def _html(self, pngs: list[Path]) -> str:
        import html

        from features import circle as fc

        rows = []
        for item, png in zip(self.circles, pngs):
            c = item.circle
            cells = [c.machine_id, c.plane, c.visit, f"{c.radius_mm:g}", f"{c.feed_mm_min:g}",
                     *(_num(item.G_um.get(d)) for d in fc.DIRECTIONS), _num(item.H_um)]
            head = "".join(f"<td>{html.escape(str(v))}</td>" for v in cells)
            diag = "<br>".join(f"{html.escape(label)} {v:.2f} ± {u:.2f}"
                               for label, v, u in item.diagnosis_lines()) if item.diagnosis else ""
            rows.append(f"<tr>{head}<td>{diag}</td></tr>")
        header = "".join(f"<th>{h}</th>" for h in (
            "machine", "plane", "visit", "R [mm]", "F [mm/min]", "G CW [um]", "G CCW [um]",
            "H [um]", "diagnosis (± standard uncertainty)"))
        images = "".join(f'<p><img src="{html.escape(p.name)}" alt="{html.escape(p.stem)}"></p>'
                         for p in pngs)
        notes = "".join(f'<p class="alert">{html.escape(n)}</p>' for n in self.notes)
        return (f'<p class="summary">{html.escape(self.source)}: {len(self.circles)} circular '
                f"tests</p>{notes}<table><tr>{header}</tr>{''.join(rows)}</table>{images}")


def _num(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def plot_names(items: list[CircleFigures]) -> list[str]:
    """``circle_<machine>_<plane>_<visit>.png`` (characters other than letters, digits, ``.``,
    ``-`` and ``_`` replaced by ``_``); a name taken twice gets ``-2``, ``-3``..."""
    names, taken = [], set()
    for item in items:
        c = item.circle
        stem = re.sub(r"[^\w.-]", "_", f"circle_{c.machine_id}_{c.plane}_{c.visit}",
                      flags=re.ASCII)
        name, k = f"{stem}.png", 2
        while name.lower() in taken:
            name, k = f"{stem}-{k}.png", k + 1
        taken.add(name.lower())
        names.append(name)
    return names


def evaluate(circle) -> CircleFigures:
    """G of each run; H and the diagnosis when both directions were run."""
    from features import circle as fc
    from models.machine import circle as mc

    g = {d: (fc.circular_deviation(circle.runs[d].angle_deg, circle.runs[d].deviation_um)
             if d in circle.runs else None) for d in fc.DIRECTIONS}
    if len(circle.runs) < 2:
        return CircleFigures(circle, g, None, None)
    runs = [r.fit_run() for r in circle.runs.values()]
    return CircleFigures(circle, g, fc.hysteresis(circle.runs["CW"], circle.runs["CCW"]),
                         mc.diagnose(runs, circle.radius_mm, circle.feed_mm_min))


def _name(circle) -> str:
    return f"{circle.machine_id} {circle.plane} visit {circle.visit}"


def _negative_play(item: CircleFigures, file) -> str | None:
    """A diagnosed circle whose play comes out negative beyond its uncertainty: refused when
    the runs fit the signatures clearly better with CW and CCW exchanged (the labels are
    swapped), else a note (an over-compensated axis, or swapped labels the fit cannot tell)."""
    from features.readings.errors import InputError
    from models.machine import circle as mc

    c, d = item.circle, item.diagnosis
    negative = mc.negative_plays(d)
    if not negative:
        return None
    axes = dict(zip(("backlash_1", "backlash_2"), c.axes))
    found = ", ".join(f"{axes[t]} {d.value[t]:.2f} ± {d.u[t]:.2f} um" for t in negative)
    increasing = f"{c.plane}: from +{c.axes[0]} towards +{c.axes[1]}"
    runs = [r.fit_run() for r in c.runs.values()]
    other = mc.swapped_fit(runs, c.radius_mm, c.feed_mm_min, d)
    if other is not None:
        exchanged = ", ".join(f"{axes[t]} {other.value[t]:.2f} um" for t in axes)
        where = {"file": file} if file is not None else {"parameter": "data"}
        raise InputError(
            f"{_name(c)}: the CW and CCW labels look swapped: as labelled the backlash comes out "
            f"negative ({found}), and with the labels exchanged the runs fit "
            f"{d.rms_residual_um / other.rms_residual_um:.1f} times closer (rms "
            f"{other.rms_residual_um:.2f} against {d.rms_residual_um:.2f} um; backlash "
            f"{exchanged}); CCW is the direction of increasing angle ({increasing})",
            column="direction", **where)
    return (f"{_name(c)}: negative backlash beyond {mc.NEGATIVE_K:g} standard uncertainties "
            f"({found}): the axis is over-compensated (its backlash compensation exceeds its "
            f"play), or the CW and CCW labels are swapped (CCW is the direction of increasing "
            f"angle, {increasing})")


def circle(data, *, tolerance_um: float | None = None) -> CircleResult:
    """Evaluate circular tests: ISO 230-4 G and H and the diagnosis of each circle.

    Parameters
    ----------
    data : str, path-like or DataFrame
        A circular-test table, CSV or Parquet (SCHEMA.md section 11, docs/circle.md).
    tolerance_um : float, optional
        Width of the tolerance band drawn in the polar plots [um] (e.g. the G a machine's
        acceptance allows); not drawn when not given.

    Returns
    -------
    CircleResult
        One ``CircleFigures`` per machine, plane, visit, radius and feed: G per direction
        [um], H [um] and the diagnosis (play and reversal spike per axis [um],
        out-of-squareness [um/m], scale mismatch [ppm], servo mismatch [ms], each with its
        standard uncertainty).

    Raises
    ------
    InputError
        The file breaks the contract (naming file, row and column).

    References
    ----------
    ISO 230-4:2022, Circular tests for numerically controlled machine tools.
    """
    from features import circle as fc
    from features.readings.errors import note

    frame = fc.read_circles(data)
    items = [evaluate(c) for c in fc.circles(frame)]
    file = data if isinstance(data, (str, os.PathLike)) else None
    notes = [fc.small_span_note(frame)]
    for item in items:
        if item.diagnosis is None:
            notes.append(f"{_name(item.circle)}: only {next(iter(item.circle.runs))} was run: G "
                         "only, no H and no diagnosis (they need CW and CCW)")
        else:
            notes.append(_negative_play(item, file))
    notes = [text for text in notes if text]
    for text in notes:
        note(text)
    source = str(data) if file is not None else "<frame>"
    return CircleResult(circles=items, source=source, tolerance_um=tolerance_um,
                        parameters={"tolerance_um": tolerance_um}, notes=notes,
                        dates=circle_days(frame))


def circle_days(frame) -> dict | None:
    """The day (ISO, UTC) of each circle, (machine, plane, visit, radius, feed) -> the
    earliest ``started_at`` of its runs (``frame``: the circle readings, a DataFrame): what
    dates its backlash in a fleet store; None when a row has no ``started_at``."""
    from features import circle as fc

    if "started_at" not in frame or frame["started_at"].isna().any():
        return None
    first = frame.groupby(list(fc.CIRCLE_KEYS), sort=False)["started_at"].min()
    return {(str(m), str(p), str(v), float(r), float(f)): t.date().isoformat()
            for (m, p, v, r, f), t in first.items()}
