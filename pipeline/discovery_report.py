"""Report of the missing-effect workflow: residual maps before and after, the gap per step next
to the repeatability, and each step's evidence (HTML + PNG)."""

from __future__ import annotations

import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from features.readings.fileio import atomic_path, write_text


def plot(result, readings, path: Path) -> Path:
    x = readings["target"].to_numpy(float)
    up = readings["direction"].to_numpy() == "+"
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, resid, title in ((axes[0], result.residual_before, "residual, baseline"),
                             (axes[1], result.residual_after, "residual, final model")):
        ax.plot(x[up], resid[up], ".", ms=3, alpha=0.5, label="+ approach")
        ax.plot(x[~up], resid[~up], ".", ms=3, alpha=0.5, label="- approach")
        ax.axhline(0, color="black", lw=0.6)
        ax.set_xlabel("target [mm]")
        ax.set_ylabel("measured - simulated [um]")
        ax.set_title(title)
        ax.legend(fontsize=7)
    lim = max(np.abs(result.residual_before).max(), 1e-9)
    axes[0].set_ylim(-lim, lim)
    axes[1].set_ylim(-lim, lim)
    labels = ["baseline", *[f"+ {s.effect}" for s in result.steps]]
    gaps = [result.rmse_before_um, *[s.rmse_after_um for s in result.steps]]
    axes[2].bar(range(len(gaps)), gaps, color="#1f5f99")
    axes[2].axhline(result.repeatability_um, color="red", ls="--", label="repeatability")
    axes[2].set_xticks(range(len(gaps)), labels, rotation=20, ha="right", fontsize=8)
    axes[2].set_ylabel("gap: RMSE simulation vs measurement [um]")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path


def write(result, readings, out_dir, source: str = "") -> dict:
    out = Path(out_dir)
    png = plot(result, readings, out / "discovery.png")
    steps = "".join(
        f"<tr><td>{i}</td><td>{s.effect}</td><td>{html.escape(str(s.parameters))}</td>"
        f"<td>{html.escape(str(s.interval))}</td><td>{s.delta_bic:.1f}</td>"
        f"<td>{100 * s.cv_gain:.1f} %</td><td>{s.rmse_before_um:.3f}</td>"
        f"<td>{s.rmse_after_um:.3f}</td></tr>" for i, s in enumerate(result.steps, 1))
    evidence = "".join(
        f"<h3>Candidates at step {i}</h3>"
        + table.drop(columns=["sse"], errors="ignore").to_html(index=False, float_format="%.3g")
        for i, table in enumerate(result.evidence, 1))
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in result.notes)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>Missing-effect report</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px}}</style></head><body>
<h1>Missing effects: {html.escape(source)}</h1>
<p>Named: <b>{', '.join(result.named) or 'none'}</b>; ambiguous:
{html.escape('; '.join(', '.join(g) for g in result.ambiguous) or 'none')}.
Gap {result.rmse_before_um:.3f} um → {result.rmse_after_um:.3f} um; repeatability
{result.repeatability_um:.3f} um.</p>
<img src="{png.name}" style="width:100%">
<h2>Steps</h2><table><tr><th>#</th><th>effect</th><th>parameters</th><th>95 % interval</th>
<th>ΔBIC</th><th>CV gain</th><th>gap before [um]</th><th>gap after [um]</th></tr>{steps}</table>
<h2>Evidence</h2>{evidence}<h2>Notes</h2><ul>{notes}</ul></body></html>"""
    return {"html": write_text(out / "discovery.html", page), "png": png}
