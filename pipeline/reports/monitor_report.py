"""The monitor's report page: each machine axis's daily lost motion with its uncertainty, the
change points and the trend, and a table of the days."""

from __future__ import annotations

import html
from pathlib import Path

from pipeline.reports.report_page import new_figure, save_figure, write_page


def write_monitor_report(result, out) -> dict[str, Path]:
    """``monitor.png`` (one panel per axis) and ``monitor.html`` under ``out``."""
    out = Path(out)
    files = {}
    if result.axes:
        files["png"] = plot_axes(result.axes, out / "monitor.png")
    files["html"] = write_page(out / "monitor.html", "Lost motion from controller traces",
                               render_body(result, "png" in files))
    return files


def plot_axes(axes, path) -> Path:
    """Daily lost motion ± 2u per axis, change points as dashed lines."""
    import pandas as pd

    fig, panels = new_figure(8.0, 2.2 * len(axes) + 0.4, nrows=len(axes), ncols=1,
                             squeeze=False, sharex=True)
    for ax, a in zip(panels[:, 0], axes):
        dates = pd.to_datetime(a.days["date"])
        ax.errorbar(dates, a.days["lost_motion_um"], yerr=2 * a.days["lost_motion_u_um"],
                    fmt="o", ms=3, color="#1f5f99", ecolor="#8fb3d6", capsize=2)
        for cp in a.change_points:
            ax.axvline(pd.Timestamp(cp), color="#b8431f", ls="--", lw=1)
        ax.set_ylabel(f"lost motion [{a.unit}]")
        ax.set_title(f"{a.machine_id} {a.axis}", fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    fig.autofmt_xdate()
    return save_figure(fig, path)


def render_body(result, chart: bool) -> str:
    e = html.escape
    parts = [(f'<p class="summary">Traces: {e(result.source)}; engine {e(result.engine)}; '
             f"{len(result.axes)} machine axes, {len(result.daily)} axis-days. Lost motion is "
             "the motor travel the load does not follow at a reversal (motor-side minus "
             "load-side position, lead error and servo lag separated), with its standard "
             "uncertainty u.</p>")]
    parts += [f'<p class="alert">{e(a["machine_id"])} {e(a["axis"])}: {e(a["message"])}</p>'
              for a in result.alerts]
    parts += [f"<p>note: {e(n)}</p>" for n in result.notes]
    if chart:
        parts.append('<img src="monitor.png" alt="daily lost motion per axis">')
    for a in result.axes:
        slope = "-" if a.slope_um_per_day is None else f"{a.slope_um_per_day:.4f}"
        parts.append(f"<h2>{e(a.machine_id)} {e(a.axis)}</h2><p>change points: "
                     f"{e(', '.join(a.change_points) or 'none')}; slope since the last: {slope} "
                     f"{e(a.unit)}/day</p>")
        rows = "".join(
            f'<tr><td>{e(r.date)}</td><td class="num">{r.lost_motion_um:.3f}</td>'
            f'<td class="num">{r.lost_motion_u_um:.3f}</td><td class="num">{r.reversals}</td>'
            f'<td class="num">{r.samples}</td></tr>' for r in a.days.itertuples())
        parts.append(f"<table><tr><th>date</th><th>lost motion [{e(a.unit)}]</th>"
                     f"<th>u [{e(a.unit)}]</th><th>reversals</th><th>samples</th></tr>"
                     f"{rows}</table>")
    return "\n".join(parts)
