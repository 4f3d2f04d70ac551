"""HTML report of the closed-loop check: ISO figures and chart before and after, per axis."""

from __future__ import annotations

import html
from pathlib import Path

from pipeline.compensation.verify import FIGURES
from pipeline.reports.report_page import new_figure, save_figure, write_page

UP, DOWN = "#1f77b4", "#d62728"


def chart(result: dict, path) -> Path:
    """Mean deviation up and down (±2s) before and after, and the reversal values."""
    fig, axes = new_figure(11, 6.5, nrows=2, ncols=2, sharex=True,
                           gridspec_kw={"height_ratios": [3, 1]})
    for col, name in enumerate(("before", "after")):
        t = result[f"{name}_targets"]
        ax, ax_b = axes[0, col], axes[1, col]
        for side, colour in (("up", UP), ("down", DOWN)):
            mean, s = t[f"mean_{side}"], t[f"s_{side}"]
            ax.plot(t["target"], mean, "o-", color=colour, label=f"mean {side}")
            ax.fill_between(t["target"], mean - 2 * s, mean + 2 * s, color=colour, alpha=0.15)
        ax.axhline(0, color="grey", lw=0.5)
        f = result[name]
        ax.set_title(f"{name}: B {f['B']:.2f}, E {f['E']:.2f}, A {f['A']:.2f} um", fontsize=10)
        ax.set_ylabel("deviation [um]")
        ax.legend(fontsize=8)
        ax_b.bar(t["target"], t["B_i"], width=0.02 * (t["target"].max() - t["target"].min() or 1),
                 color="grey")
        ax_b.axhline(0, color="black", lw=0.5)
        ax_b.set_ylabel("B_i [um]")
        ax_b.set_xlabel("target [mm]")
    ylim = [min(a.get_ylim()[0] for a in axes[0]), max(a.get_ylim()[1] for a in axes[0])]
    for a in axes[0]:
        a.set_ylim(ylim)
    fig.suptitle(f"{result['machine_id']} {result['axis']}: ISO 230-2 before and after "
                 "compensation (twin, new session)")
    return save_figure(fig, path)


def write_report(results: list[dict], controller: str, out_dir) -> Path:
    out_dir = Path(out_dir)
    parts = [(f"<p class='summary'>Controller <b>{html.escape(controller)}</b>: the twin re-ran "
             "the ISO 230-2 tests with the written files applied by its controller model, in a "
             "new session (new noise and conditions, shared by the runs before and after). "
             "Figures are means over the tests used [um]; an axis passes when neither B nor E "
             "grows beyond the noise.</p>")]
    for r in results:
        png = chart(r, out_dir / f"verify_{r['machine_id']}_{r['axis']}.png")
        rows = "".join(
            f"<tr><td>{k}</td><td class='num'>{r['before'][k]:.3f}</td>"
            f"<td class='num'>{r['after'][k]:.3f}</td></tr>" for k in FIGURES)
        verdict = "passed" if r["passed"] else "FAILED: the compensation makes the axis worse"
        css = "summary" if r["passed"] else "alert"
        parts.append(
            f"<h2>{html.escape(str(r['machine_id']))} {html.escape(r['axis'])}</h2>"
            f"<p class='{css}'>{verdict}; B after/before {r['ratio_B']:.2f}, "
            f"E after/before {r['ratio_E']:.2f} ({r['before']['tests']} tests)</p>"
            f"<table><tr><th>figure</th><th>before</th><th>after</th></tr>{rows}</table>"
            f"<img src='{png.name}' alt='ISO chart before and after'>")
    return write_page(out_dir / "verify.html", "Compensation closed-loop check", "\n".join(parts))
