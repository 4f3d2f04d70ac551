"""The polar plot of a circular test as ballbar software draws it: both runs about their
least-squares centre, the radial deviation magnified round the nominal circle, the tolerance
band and the ISO 230-4 figures in a box."""

from __future__ import annotations

import numpy as np

from features.circle import centred
from pipeline.reports.report_page import new_figure, save_figure

COLOURS = {"CCW": "#1f77b4", "CW": "#d62728"}


def _closed(angle_deg: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted by angle and closed round the circle, when the run covers it, so that the path
    is drawn as one loop."""
    order = np.argsort(np.mod(angle_deg, 360.0))
    a, v = np.mod(angle_deg, 360.0)[order], values[order]
    if a[0] + 360.0 - a[-1] <= 3.0 * np.median(np.diff(a)):
        a, v = np.append(a, a[0] + 360.0), np.append(v, v[0])
    return np.radians(a), v


def plot_circle(item, path, tolerance_um: float | None = None):
    """Write one PNG of a circular test.

    The radius drawn is the radial deviation [um] about each run's least-squares centre, on a
    scale whose origin lies well inside the plot (as ballbar software magnifies the path), so
    a step of a few micrometres is seen on a circle of 150 mm.

    Parameters
    ----------
    item : pipeline.workflows.circle.CircleFigures
        The test, its figures and diagnosis.
    path : str or path-like
        The PNG to write.
    tolerance_um : float, optional
        Width of the tolerance band [um], drawn centred between the runs' largest and
        smallest radius.
    """
    circle = item.circle
    fig = new_figure(9.6, 6.4, fixed_margins=True)
    ax = fig.add_axes((0.03, 0.08, 0.6, 0.82), projection="polar")
    paths = {d: centred(r.angle_deg, r.deviation_um) for d, r in circle.runs.items()}
    every = np.concatenate(list(paths.values()))
    middle = float(every.max() + every.min()) / 2.0   # a path with G <= tolerance fits the band
    reach = max(float(every.max() - every.min()) / 2.0, (tolerance_um or 0.0) / 2.0, 1.0)
    low, high = middle - 1.3 * reach, middle + 1.3 * reach
    ax.set_ylim(low, high)
    ax.set_rorigin(low - 2.2 * (high - low))        # the magnified scale: zero well inside
    ring = np.linspace(0.0, 2 * np.pi, 361)
    if tolerance_um:
        ax.fill_between(ring, middle - tolerance_um / 2, middle + tolerance_um / 2,
                        color="#2ca02c", alpha=0.12, lw=0,
                        label=f"tolerance band {tolerance_um:g} um")
    for direction, dev in paths.items():
        theta, r = _closed(circle.runs[direction].angle_deg, dev)
        ax.plot(theta, r, color=COLOURS[direction], lw=1.2,
                label=f"{direction} ({circle.runs[direction].test_id})")
    first, second = circle.axes
    ax.set_thetagrids([0, 90, 180, 270], [f"+{first}", f"+{second}", f"-{first}", f"-{second}"])
    ax.set_rlabel_position(112.5)
    ax.tick_params(axis="y", labelsize=7)
    fig.suptitle(f"{circle.machine_id} {circle.plane} visit {circle.visit}: R "
                 f"{circle.radius_mm:g} mm, F {circle.feed_mm_min:g} mm/min — radial deviation "
                 "[um], magnified", fontsize=10)
    fig.legend(fontsize=8, loc="lower right", bbox_to_anchor=(0.98, 0.06))
    fig.text(0.68, 0.88, _box(item), va="top", family="monospace", fontsize=8,
             bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.9})
    return save_figure(fig, path)


def _box(item) -> str:
    """The figures and the diagnosis, one per line, ``± u`` (standard uncertainty)."""
    lines = ["ISO 230-4 [um]"]
    lines += [f"G {d:<4}{g:8.2f}" for d, g in item.G_um.items() if g is not None]
    if item.H_um is not None:
        lines.append(f"H     {item.H_um:8.2f}")
    if item.diagnosis is None:  # one direction: what it cannot give, as the note says
        lines += [f"only {next(iter(item.circle.runs))} was run:", "no H, no diagnosis",
                  "(they need CW and CCW)"]
    else:
        lines.append("diagnosis (± u)")
        for label, value, u in item.diagnosis_lines():
            lines.append(f"{label:<18}{value:8.2f} ± {u:.2f}")
    return "\n".join(lines)
