"""Report of the missing-effect workflow: residual maps before and after, the gap per step next
to the repeatability, each step's evidence, the unexplained gap and the notes (HTML + PNG)."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from pipeline.reports.report_page import new_figure, save_figure, write_page


def plot(result, readings, path: Path) -> Path:
    used = np.ones(len(readings), bool) if result.used is None else result.used
    x = readings["target"].to_numpy(float)[used]
    up = readings["direction"].to_numpy()[used] == "+"
    unit, position = result.unit, "deg" if result.unit == "arcsec" else "mm"
    fig, axes = new_figure(14, 4, ncols=3)
    for ax, resid, title in ((axes[0], result.residual_before, "residual, baseline"),
                             (axes[1], result.residual_after, "residual, final model")):
        ax.plot(x[up], resid[up], ".", ms=3, alpha=0.5, label="+ approach")
        ax.plot(x[~up], resid[~up], ".", ms=3, alpha=0.5, label="- approach")
        ax.axhline(0, color="black", lw=0.6)
        ax.set_xlabel(f"target [{position}]")
        ax.set_ylabel(f"measured - simulated [{unit}]")
        ax.set_title(title)
        ax.legend(fontsize=7)
    lim = max(float(np.abs(result.residual_before).max()), 1e-9)
    axes[0].set_ylim(-lim, lim)
    axes[1].set_ylim(-lim, lim)
    labels = ["baseline", *[f"+ {s.effect}" for s in result.steps]]
    gaps = [result.rmse_before_um, *[s.rmse_after_um for s in result.steps]]
    axes[2].bar(range(len(gaps)), gaps, color="#1f5f99")
    axes[2].axhline(result.repeatability_um, color="red", ls="--", label="repeatability")
    axes[2].set_xticks(range(len(gaps)), labels, rotation=20, ha="right", fontsize=8)
    axes[2].set_ylabel(f"gap: RMSE simulation vs measurement [{unit}]")
    axes[2].legend(fontsize=7)
    return save_figure(fig, path)


def _unexplained(gap: dict | None, unit: str) -> str:
    if not gap:
        return ""
    rows = "".join(
        f"<tr><td>{html.escape(s['against'])}</td><td class='num'>{100 * s['share']:.1f} %</td>"
        f"<td class='num'>{s['rms_um']:.3g}</td><td class='num'>{s['p_value']:.2g}</td></tr>"
        for s in gap["structure"])
    hint = (f"<p>Effects that act along it: {html.escape(', '.join(gap['candidates']))}.</p>"
            if gap.get("candidates") else "")
    return (f"<h2>Unexplained gap</h2><div class='alert'>{html.escape(gap['reason'])}</div>"
            f"{hint}<table><tr><th>residual against</th><th>share</th><th>rms [{unit}]</th>"
            f"<th>p (F-test)</th></tr>{rows}</table>")


def _system(test: dict | None, unit: str) -> str:
    """The measuring-system decision and its test, one line."""
    if not test:
        return ""
    line = (f"Measuring system: <b>{html.escape(str(test['system']))}</b> ({html.escape(test['test'])}: "
            f"mean {test['mean_um']:.3g} {unit} over {test['n']} values, t = {test['statistic']:.3g}, "
            f"p = {test['p_value']:.2g}")
    if "pendulum_statistic" in test:
        line += (f"; against the pendulum tests' {test['pendulum_mean_um']:.3g} {unit}: t = "
                 f"{test['pendulum_statistic']:.3g}, p = {test['pendulum_p_value']:.2g}")
    return f"<p>{line}).</p>"


def write(result, readings, out_dir, source: str = "") -> dict:
    out = Path(out_dir)
    png = plot(result, readings, out / "discovery.png")
    steps = "".join(
        f"<tr><td>{i}</td><td>{s.effect}</td><td>{html.escape(str(s.parameters))}</td>"
        f"<td>{html.escape(str(s.interval))}</td><td class='num'>{s.delta_bic:.1f}</td>"
        f"<td class='num'>{100 * s.cv_gain:.1f} %</td><td class='num'>{s.rmse_before_um:.3f}"
        f"</td><td class='num'>{s.rmse_after_um:.3f}</td>"
        f"<td>{html.escape(', '.join(s.not_identified)) or '-'}</td></tr>"
        for i, s in enumerate(result.steps, 1))
    evidence = "".join(
        f"<h3>Candidates at step {i}</h3>"
        + table.drop(columns=["sse"], errors="ignore").to_html(index=False, float_format="%.3g")
        for i, table in enumerate(result.evidence, 1))
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in result.notes)
    ambiguous = '; '.join(', '.join(g) for g in result.ambiguous) or 'none'
    unit = result.unit
    system = _system(result.measuring_system, unit)
    body = f"""<div class="summary"><p>{html.escape(source)}: named
<b>{', '.join(result.named) or 'none'}</b>; ambiguous: {html.escape(ambiguous)}.
Gap {result.rmse_before_um:.3f} {unit} &rarr; {result.rmse_after_um:.3f} {unit}; repeatability
{result.repeatability_um:.3f} {unit}.</p>{system}</div>
<img src="{png.name}" alt="residuals and gap per step">
<h2>Steps</h2><table><tr><th>#</th><th>effect</th><th>parameters</th><th>95 % interval</th>
<th>&Delta;BIC</th><th>CV gain</th><th>gap before [{unit}]</th><th>gap after [{unit}]</th>
<th>not identified</th></tr>{steps}</table>
{_unexplained(result.unexplained, unit)}
<h2>Notes</h2><ul>{notes}</ul><h2>Evidence</h2>{evidence}"""
    return {"html": write_page(out / "discovery.html", "Missing physical effects", body),
            "png": png}
