"""The figures and the written report of the backlash paper's replication: Fig. 10 (training
curves), Fig. 13 (regression of output against target) and the side-by-side table as Markdown,
JSON and HTML, from the numbers ``pipeline.replication.fitting.replicate`` returns.
"""

from __future__ import annotations

import html
from pathlib import Path

from features.readings.fileio import clean_nan, write_json, write_text
from pipeline.replication.fitting import PAPER, PAPER_TABLE5, comparison_rows
from pipeline.reports.report_page import new_figure, save_figure, write_page

FILES = {"html": "replication.html", "md": "replication.md", "json": "replication.json",
         "fig10": "replication_fig10.png", "fig13": "replication_fig13.png"}


def markdown(rows: list[dict]) -> str:
    """The side-by-side table (``comparison_rows``) as Markdown."""
    lines = ["| quantity | paper | twin, 8 inputs | twin, without deviations | note |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['quantity']} | {r['paper']} | {r['with']} | {r['without']} | {r['note']} |"
              for r in rows]
    return "\n".join(lines) + "\n"


def plot_fig10(results: dict, path) -> Path:
    """Fig. 10: training, validation and test error per epoch, one panel per case."""
    fig, axes = new_figure(10, 4, nrows=1, ncols=2, sharey=True)
    for ax, (case, result) in zip(axes, results.items(), strict=True):
        net = result["network"]
        for key, label in (("train_mse", "training"), ("val_mse", "validation"),
                           ("test_mse", "test")):
            ax.semilogy(net["history"][key], label=label)
        ax.axvline(net["best_epoch"], color="grey", ls="--",
                   label=f"best epoch {net['best_epoch']} of {net['epochs']}")
        ax.set_title(f"Fig. 10, {case}", fontsize=10)
        ax.set_xlabel("epoch")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("mean squared error (scaled target)")
    return save_figure(fig, path)


def plot_fig13(results: dict, path) -> Path:
    """Fig. 13: output against target per phase, with the deviation inputs."""
    fig, axes = new_figure(10, 9, nrows=2, ncols=2)
    net = results["with deviations"]["network"]
    for ax, (phase, rows) in zip(axes.ravel(), net["parts"].items(), strict=True):
        t, o = net["target"][rows], net["output"][rows]
        ax.plot(t, o, "o", ms=3, alpha=0.7)
        lo, hi = float(min(t.min(), o.min())), float(max(t.max(), o.max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_title(f"{phase}: R = {net['regression_r'][phase]:.3f}", fontsize=10)
        ax.set_xlabel("target [um]")
        ax.set_ylabel("output [um]")
    return save_figure(fig, path)


def write_replication(results: dict, out_dir, source: str = "") -> dict[str, Path]:
    """The table as Markdown, JSON and HTML and both figures in ``out_dir`` (``FILES``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / v for k, v in FILES.items()}
    rows = comparison_rows(results)
    write_text(paths["md"], markdown(rows))
    plot_fig10(results, paths["fig10"])
    plot_fig13(results, paths["fig13"])
    summary = {case: {k: v for k, v in r.items() if k != "network"}
               | {"network": {k: v for k, v in r["network"].items()
                              if k not in ("target", "output", "parts")}}
               for case, r in results.items()}
    write_json(paths["json"], clean_nan({"paper": {**PAPER, "table5": PAPER_TABLE5},
                                         "twin": summary, "table": rows}))
    body_rows = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(r[k]))}</td>"
                         for k in ("quantity", "paper", "with", "without", "note")) + "</tr>"
        for r in rows)
    write_page(paths["html"], "Replication of the backlash paper", f"""
<p>Data: <code>{html.escape(source)}</code>. The paper's inputs include the linear-test
deviations from which the backlash target is computed: they carry the target itself, so the
scores are shown with and without them.</p>
<table><tr><th>quantity</th><th>paper</th><th>twin, 8 inputs</th>
<th>twin, without deviations</th><th>note</th></tr>{body_rows}</table>
<img src="{FILES['fig10']}" alt="training curves"><img src="{FILES['fig13']}" alt="regression">
""")
    return paths
