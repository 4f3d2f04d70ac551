"""Feature-ranking report: one HTML page with its PNG figures, a CSV table and a JSON summary.

Files written to the output folder (images are referenced by relative file name, so the
folder can be moved or zipped as a whole):

====================  ==================================================================
``rank_report.html``  the report
``rank_anova.png``    ANOVA score -ln(p) per input with bootstrap error bars (seed 004,
                      Fig. 14)
``rank_views.png``    permutation importance, mutual information and k-NN drop-column
                      loss per input, with their spreads
``rank_confusion.png``  cross-validated confusion matrix of the weighted k-NN
``rank_table.csv``    every score per input, ordered by rank
``rank.json``         the ``--json`` summary
====================  ==================================================================
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from features.readings.fileio import atomic_path, clean_nan, write_json, write_text

# Seed 004, Table 5: ANOVA scores -log(p) on the FM38 X axis, for comparison only.
PAPER_TABLE5 = {
    "target": 24.724, "deviation_down_um": 22.099, "deviation_up_um": 20.093,
    "feed_mm_min": 3.217, "machine_temp_c": 1.424, "ambient_temp_c": 1.040,
    "pressure_hpa": 0.417, "humidity_pct": 0.108,
}
FILES = {
    "html": "rank_report.html", "anova": "rank_anova.png", "views": "rank_views.png",
    "confusion": "rank_confusion.png", "csv": "rank_table.csv", "json": "rank.json",
}


def write_rank_report(ranking, out_dir, *, source: str = "", target_kind: str = "",
                      notes: list[str] | tuple = ()) -> dict[str, Path]:
    """Write the report files (module docstring) for a ``features.ranking.Ranking``.

    Returns
    -------
    dict
        File role -> path of every file written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {role: out / name for role, name in FILES.items()}
    plot_anova(ranking, paths["anova"])
    plot_views(ranking, paths["views"])
    plot_confusion(ranking, paths["confusion"])
    with atomic_path(paths["csv"]) as tmp:
        ranking.table.to_csv(tmp)
    write_json(paths["json"], clean_nan(ranking.to_json()))
    all_notes = [*ranking.notes, *notes]
    write_text(paths["html"], render_html(ranking, source=source, target_kind=target_kind,
                                          notes=all_notes))
    return paths


# --- figures --------------------------------------------------------------------------------

def _figure(width_in: float, height_in: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=110, layout="constrained")


def _save(fig, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def plot_anova(ranking, path) -> None:
    """Bar chart of -ln(p) per input in rank order, error bars = bootstrap std (Fig. 14)."""
    from features.ranking import ANOVA_ALPHA

    t = ranking.table
    fig = _figure(7.5, 4.2)
    ax = fig.add_subplot()
    x = np.arange(len(t))
    colours = np.where(t["influence"], "#1f5f99", "#9aa7b4")
    ax.bar(x, t["anova_score"], yerr=t["anova_score_std"], color=colours, capsize=3)
    ax.axhline(-np.log(ANOVA_ALPHA), color="#b03a2e", ls="--", lw=1)
    ax.annotate(f"p = {ANOVA_ALPHA:g}", (len(t) - 0.5, -np.log(ANOVA_ALPHA)), ha="right",
                va="bottom", color="#b03a2e", fontsize=8)
    ax.set_xticks(x, t["label"], rotation=30, ha="right")
    ax.set_ylabel("ANOVA score  -ln(p)")
    ax.set_title("Influence of the inputs on backlash classes (one-way ANOVA)")
    ax.set_ylim(bottom=0)
    _save(fig, path)


def plot_views(ranking, path) -> None:
    """Permutation importance [um], mutual information [nat] and k-NN drop-column loss."""
    t = ranking.table
    fig = _figure(7.5, 7.5)
    axes = fig.subplots(3, 1, sharex=True)
    x = np.arange(len(t))
    panels = [
        ("permutation_um", "permutation_std_um", "RMSE increase [um]",
         f"Permutation importance ({ranking.permutation_model})"),
        ("mutual_info", "mutual_info_std", "mutual information [nat]",
         "Mutual information (bars) and noise level (markers)"),
        ("knn_drop", "knn_drop_std", "accuracy loss [-]",
         "k-NN drop-column accuracy loss"),
    ]
    for ax, (col, err, ylabel, title) in zip(axes, panels, strict=True):
        ax.bar(x, t[col], yerr=t[err], color="#1f5f99", capsize=3)
        ax.axhline(0.0, color="black", lw=0.6)
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=9)
    axes[1].plot(x, t["mutual_info_null"], "_", color="#b03a2e", ms=18, mew=2)
    axes[-1].set_xticks(x, t["label"], rotation=30, ha="right")
    _save(fig, path)


def plot_confusion(ranking, path) -> None:
    """Confusion matrix of the cross-validated weighted k-NN, counts in every cell."""
    knn = ranking.knn
    matrix = knn.confusion
    fig = _figure(5.6, 4.8)
    ax = fig.add_subplot()
    image = ax.imshow(matrix, cmap="Blues")
    fig.colorbar(image, ax=ax, label="points")
    ticks = np.arange(matrix.shape[0])
    ax.set_xticks(ticks, knn.class_labels, rotation=30, ha="right")
    ax.set_yticks(ticks, knn.class_labels)
    ax.set_xlabel("predicted backlash class")
    ax.set_ylabel("true backlash class")
    ax.set_title(f"Weighted k-NN (k = {knn.n_neighbors}): accuracy "
                 f"{100 * knn.accuracy:.1f} ± {100 * knn.accuracy_std:.1f} %", fontsize=10)
    threshold = matrix.max() / 2
    for (i, j), count in np.ndenumerate(matrix):
        ax.text(j, i, str(count), ha="center", va="center",
                color="white" if count > threshold else "black")
    _save(fig, path)


# --- HTML -----------------------------------------------------------------------------------

CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 1.5em auto;
       padding: 0 1em; color: #1d2329; line-height: 1.45; }
h1 { font-size: 1.6em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccd; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccd; padding: 0.25em 0.55em; vertical-align: top; }
th { background: #eef1f5; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tr.weak td { color: #69737d; }
img { max-width: 100%; border: 1px solid #dde; margin: 0.4em 0; }
.summary { background: #f4f7fa; padding: 0.6em 1em; border-left: 4px solid #1f5f99; }
"""


def _pm(value, spread, fmt: str = ".3g") -> str:
    """``value ± spread`` for HTML; the spread with two significant digits."""
    if value is None or not np.isfinite(value):
        return "n/a" if value is None or np.isnan(value) else "&infin;"
    text = f"{value:{fmt}}"
    return f"{text} &plusmn; {spread:.2g}" if np.isfinite(spread) else text


def _summary(table) -> str:
    groups = {
        "Drivers, strongest first": table[table["influence"] & ~table["proxy_for_visit"]],
        "Proxies for the visit": table[table["proxy_for_visit"]],
        "No measurable influence": table[~table["influence"] & ~table["proxy_for_visit"]],
    }
    lines = [f"<li><b>{name}:</b> {html.escape(', '.join(rows['label'])) or 'none'}</li>"
             for name, rows in groups.items()]
    return "<ul>" + "".join(lines) + "</ul>"


def _ranking_rows(table) -> str:
    from features.ranking import format_p

    rows = []
    for name, r in table.iterrows():
        cls = "" if r["influence"] else ' class="weak"'
        rows.append(
            f"<tr{cls}><td class='num'>{int(r['rank'])}</td>"
            f"<td>{html.escape(r['label'])}<br><code>{html.escape(name)}</code></td>"
            f"<td class='num'>{_pm(r['anova_score'], r['anova_score_std'], '.3f')}<br>"
            f"{html.escape(format_p(r['anova_score']))}</td>"
            f"<td class='num'>{_pm(r['permutation_um'], r['permutation_std_um'])}</td>"
            f"<td class='num'>{_pm(r['mutual_info'], r['mutual_info_std'])}<br>"
            f"noise {r['mutual_info_null']:.2g}</td>"
            f"<td class='num'>{_pm(r['knn_drop'], r['knn_drop_std'])}</td>"
            f"<td>{html.escape(r['reading'])}</td></tr>")
    return "".join(rows)


def _table5_rows(table) -> str:
    rows = []
    for name, r in table.iterrows():
        paper = PAPER_TABLE5.get(name)
        rows.append(f"<tr><td>{html.escape(r['label'])}</td>"
                    f"<td class='num'>{_pm(r['anova_score'], r['anova_score_std'], '.3f')}</td>"
                    f"<td class='num'>{'' if paper is None else f'{paper:.3f}'}</td></tr>")
    return "".join(rows)


def _confusion_table(knn) -> str:
    labels = [html.escape(c) for c in knn.class_labels]
    head = "".join(f"<th>{c}</th>" for c in labels)
    body = "".join(
        f"<tr><th>{labels[i]} ({knn.class_counts[i]})</th>"
        + "".join(f"<td class='num'>{v}</td>" for v in row) + "</tr>"
        for i, row in enumerate(knn.confusion))
    return (f"<table><tr><th>true \\ predicted</th>{head}</tr>{body}</table>")


def render_html(ranking, *, source: str = "", target_kind: str = "",
                notes: list[str] | tuple = ()) -> str:
    """The report page; images are the relative PNG files of ``FILES``."""
    from features import ranking as rk

    t = ranking.table
    knn = ranking.knn
    folds = ", ".join(f"{100 * a:.1f}" for a in knn.fold_accuracy)
    note_items = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
    target_line = f", backlash target <code>{html.escape(target_kind)}</code>" \
        if target_kind else ""
    rule = ("mean of the per-view ranks of ANOVA score, permutation importance and mutual "
            "information; ties broken by the ANOVA score" if ranking.rank_by == "consensus"
            else "ANOVA score (three decimals, as the paper's Table 5); ties broken by the "
                 "permutation importance")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>Backlash feature ranking</title><style>{CSS}</style></head>
<body>
<h1>Which conditions drive backlash</h1>
<p>Data: <code>{html.escape(source)}</code> &mdash; {ranking.n_points} backlash points,
{len(t)} inputs{target_line}.</p>
<div class="summary">{_summary(t)}</div>

<h2>Ranking</h2>
<p>Rank rule: {rule}. Grey rows: no measurable influence (ANOVA p &ge; {rk.ANOVA_ALPHA:g},
permutation importance within twice its spread or below {100 * rk.PERMUTATION_FLOOR:g} % of the
strongest input's, and mutual information at noise level).</p>
<table>
<tr><th>rank</th><th>input</th><th>ANOVA score -ln(p)</th><th>permutation [um]</th>
<th>mutual information [nat]</th><th>k-NN drop-column</th><th>physical reading</th></tr>
{_ranking_rows(t)}
</table>

<h2>ANOVA scores (paper Fig. 14 and Table 5)</h2>
<img src="{FILES['anova']}" alt="ANOVA score per input with bootstrap error bars">
<table><tr><th>parameter</th><th>ANOVA score -ln(p), these data</th>
<th>paper, FM38 X axis</th></tr>
{_table5_rows(t)}
</table>
<p>The paper's column is the published Table 5 of a different machine, shown for scale
only. Scores grow with the number of points, so compare the order, not the values.</p>

<h2>Weighted k-NN classification</h2>
<p>Backlash split into {len(knn.class_counts)} classes; weighted k-NN (k = {knn.n_neighbors},
weights 1/distance, standardised inputs), {knn.n_splits}-fold stratified cross-validation:
validation accuracy <b>{100 * knn.accuracy:.1f} &plusmn; {100 * knn.accuracy_std:.1f} %</b>
(folds: {folds} %; always guessing the largest class: {100 * knn.majority_rate:.1f} %).
The paper reports 98.8 %.</p>
<img src="{FILES['confusion']}" alt="k-NN confusion matrix">
{_confusion_table(knn)}

<h2>Permutation importance, mutual information, k-NN drop-column</h2>
<img src="{FILES['views']}" alt="permutation importance, mutual information and k-NN loss">

<h2>Method</h2>
<ul>
<li><b>ANOVA score</b>: -ln(p) of the one-way F-test of each input across the backlash
classes, from the log survival function so that tiny p stays finite; &plusmn; is the std over
bootstrap resamples of the points.</li>
<li><b>Permutation importance</b>: increase of the held-out RMSE [um] when the input is
shuffled; predictor: {html.escape(ranking.permutation_model)}; &plusmn; is the std over folds
and shuffles (over shuffles only for a given fitted predictor).</li>
<li><b>Mutual information</b> (k-neighbour estimator, seeded): &plusmn; is the std over random
80 % subsamples; the noise level is the mean + 3 std with the backlash shuffled.</li>
<li><b>k-NN drop-column</b>: validation accuracy with all inputs minus accuracy without the
input, per fold; &plusmn; is the std over folds.</li>
<li>An input constant within each visit but varying between visits is a <b>proxy for the
visit</b>: its score cannot be told apart from anything else that changed between visits.</li>
</ul>
{f"<h2>Notes</h2><ul>{note_items}</ul>" if note_items else ""}
</body></html>
"""
