"""Feature report: verdicts given the other inputs first, then the paper's association views.

Files written to the output folder (images are referenced by relative file name, so the
folder can be moved or zipped as a whole):

======================  ================================================================
``rank_report.html``    the report: headline (drivers only), verdict table, design
                        diagnostics, then the association views of the paper
``rank_effects.png``    effect [um] of each input over its observed range with its
                        bootstrap interval, coloured by verdict
``rank_anova.png``      association: ANOVA score -ln(p) per input with bootstrap error bars
                        ([BacklashNN], Fig. 14)
``rank_views.png``      association: permutation importance, mutual information, k-NN
                        drop-column loss; and the drop-column importance of gradient boosting
``rank_confusion.png``  cross-validated confusion matrix of the weighted k-NN
``rank_table.csv``      every score and verdict per input, in report order
``rank.json``           the ``--json`` summary
======================  ================================================================
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from features.readings.fileio import atomic_path, clean_nan, write_json
from pipeline.reports.report_page import new_figure, save_figure, write_page

# Seed 004, Table 5: ANOVA scores -log(p) on the FM38 X axis, for comparison only.
PAPER_TABLE5 = {
    "target": 24.724, "deviation_down_um": 22.099, "deviation_up_um": 20.093,
    "feed_mm_min": 3.217, "machine_temp_c": 1.424, "ambient_temp_c": 1.040,
    "pressure_hpa": 0.417, "humidity_pct": 0.108,
}
FILES = {
    "html": "rank_report.html", "effects": "rank_effects.png", "anova": "rank_anova.png",
    "views": "rank_views.png", "confusion": "rank_confusion.png", "csv": "rank_table.csv",
    "json": "rank.json",
}
COLOURS = {"driver": "#1f5f99", "proxy": "#d08a2c", "undecided": "#8e6bb0", "none": "#9aa7b4"}
LEVEL_WORDS = {"point": "within runs", "run": "between runs", "visit": "between visits",
               "unit": "between machines/axes", None: "not tested"}


def write_rank_report(result, out_dir, *, source: str = "", target_kind: str = "",
                      notes: list[str] | tuple = (), unit: str = "um") -> dict[str, Path]:
    """Write the report files (module docstring) for a ``models.influence.Explanation``;
    ``unit`` of the backlash: um, or arcsec for rotary axes.

    Returns
    -------
    dict
        File role -> path of every file written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {role: out / name for role, name in FILES.items()}
    plot_effects(result, paths["effects"], unit)
    plot_anova(result, paths["anova"])
    plot_views(result, paths["views"], unit)
    plot_confusion(result, paths["confusion"])
    table = result.table.drop(columns=["degrees"], errors="ignore").copy()
    table["physical_path"] = [",".join(p) for p in table["physical_path"]]
    with atomic_path(paths["csv"]) as tmp:
        table.to_csv(tmp)
    write_json(paths["json"], clean_nan(result.to_dict()))
    all_notes = [*result.ranking.notes, *result.notes, *notes]
    write_page(paths["html"], "Which conditions drive backlash",
               render_body(result, source=source, target_kind=target_kind, notes=all_notes,
                           unit=unit))
    return paths


# --- figures --------------------------------------------------------------------------------

def plot_effects(result, path, unit: str = "um") -> Path:
    """Effect [um] (``unit``) over the observed range with its 95 % bootstrap interval, per verdict."""
    t = result.table
    fig = new_figure(7.5, 4.2)
    ax = fig.add_subplot()
    x = np.arange(len(t))
    effect = t["effect_um"].fillna(0.0).to_numpy(float)
    low = np.nan_to_num(effect - t["effect_low_um"].to_numpy(float)).clip(0, None)
    high = np.nan_to_num(t["effect_high_um"].to_numpy(float) - effect).clip(0, None)
    ax.bar(x, effect, yerr=[low, high], capsize=3,
           color=[COLOURS.get(v, "#9aa7b4") for v in t["verdict"]])
    ax.set_xticks(x, t["label"], rotation=30, ha="right")
    ax.set_ylabel(f"effect over the observed range [{unit}]")
    ax.set_title("Effect of each input given the others (colour: driver, proxy, "
                 "undecided, none)", fontsize=9)
    ax.set_ylim(bottom=0)
    return save_figure(fig, path)


def plot_anova(result, path) -> Path:
    """Association: -ln(p) per input in report order, error bars = bootstrap std (Fig. 14)."""
    from features.ranking import ANOVA_ALPHA

    t = result.table
    fig = new_figure(7.5, 4.2)
    ax = fig.add_subplot()
    x = np.arange(len(t))
    ax.bar(x, t["anova_score"], yerr=t["anova_score_std"], capsize=3,
           color=np.where(t["influence"], "#1f5f99", "#9aa7b4"))
    ax.axhline(-np.log(ANOVA_ALPHA), color="#b03a2e", ls="--", lw=1)
    ax.annotate(f"p = {ANOVA_ALPHA:g}", (len(t) - 0.5, -np.log(ANOVA_ALPHA)), ha="right",
                va="bottom", color="#b03a2e", fontsize=8)
    ax.set_xticks(x, t["label"], rotation=30, ha="right")
    ax.set_ylabel("ANOVA score  -ln(p)")
    ax.set_title("Association with backlash classes (one-way ANOVA, the paper's Fig. 14)",
                 fontsize=9)
    ax.set_ylim(bottom=0)
    return save_figure(fig, path)


def plot_views(result, path, unit: str = "um") -> Path:
    """Permutation importance, mutual information, k-NN drop-column loss and the drop-column
    importance of gradient boosting (when computed)."""
    t = result.table
    panels = [
        ("permutation_um", "permutation_std_um", f"RMSE increase [{unit}]",
         f"Association: permutation importance ({result.ranking.permutation_model})"),
        ("mutual_info", "mutual_info_std", "mutual information [nat]",
         "Association: mutual information (bars) and noise level (markers)"),
        ("knn_drop", "knn_drop_std", "accuracy loss [-]",
         "Association: k-NN drop-column accuracy loss"),
    ]
    if "dropcolumn_um" in t:
        panels.append(("dropcolumn_um", "dropcolumn_std_um", f"RMSE increase [{unit}]",
                       ("Given the others: drop-column importance of gradient boosting, "
                        "CV grouped by visit or run")))
    fig, axes = new_figure(7.5, 2.5 * len(panels), nrows=len(panels), ncols=1, sharex=True)
    x = np.arange(len(t))
    for ax, (col, err, ylabel, title) in zip(axes, panels, strict=True):
        ax.bar(x, t[col], yerr=t[err], color="#1f5f99", capsize=3)
        ax.axhline(0.0, color="black", lw=0.6)
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=9)
    axes[1].plot(x, t["mutual_info_null"], "_", color="#b03a2e", ms=18, mew=2)
    axes[-1].set_xticks(x, t["label"], rotation=30, ha="right")
    return save_figure(fig, path)


def plot_confusion(result, path) -> Path:
    """Confusion matrix of the cross-validated weighted k-NN, counts in every cell."""
    knn = result.knn
    matrix = knn.confusion
    fig = new_figure(5.6, 4.8)
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
    return save_figure(fig, path)


# --- HTML -----------------------------------------------------------------------------------

def _pm(value, spread, fmt: str = ".3g") -> str:
    """``value ± spread`` for HTML; the spread with two significant digits."""
    if value is None or not np.isfinite(value):
        return "n/a" if value is None or np.isnan(value) else "&infin;"
    text = f"{value:{fmt}}"
    return f"{text} &plusmn; {spread:.2g}" if np.isfinite(spread) else text


def _effect(r) -> str:
    if not np.isfinite(r["effect_um"]):
        return "n/a"
    interval = (f" [{r['effect_low_um']:.2f}, {r['effect_high_um']:.2f}]"
                if np.isfinite(r["effect_low_um"]) else "")
    return f"{r['effect_um']:.2f}{interval}"


def _p(p) -> str:
    if p is None or not np.isfinite(p):
        return "n/a"
    return f"{p:.2g}" if p >= 1e-4 else "&lt; 1e-4"


def _headline(t, unit: str) -> str:
    drivers = t[t["verdict"] == "driver"]
    if drivers.empty:
        return ("<p><b>Drivers:</b> none measurable given the other inputs. The verdict "
                "table says what each input's association stands for.</p>")
    items = "".join(
        f"<li><b>{html.escape(r['label'])}</b>: {r['effect_um']:.2f} {unit} over the observed "
        f"range (95 % interval {r['effect_low_um']:.2f}-{r['effect_high_um']:.2f} {unit}, "
        f"{html.escape(r['effect_shape'])})</li>" for _, r in drivers.iterrows())
    return f"<p><b>Drivers, given the other inputs</b> (largest effect first):</p><ul>{items}</ul>"


def _verdict_rows(t) -> str:
    rows = []
    for name, r in t.iterrows():
        weak = "" if r["verdict"] == "driver" else ' class="weak"'
        proxy = r["proxy_for"] if isinstance(r["proxy_for"], str) else ""
        drop = (_pm(r["dropcolumn_um"], r["dropcolumn_std_um"])
                if "dropcolumn_um" in r else "n/a")
        rows.append(
            f"<tr{weak}><td>{html.escape(r['label'])}<br><code>{html.escape(name)}</code></td>"
            f"<td><b>{html.escape(r['verdict'])}</b></td>"
            f"<td class='num'>{_effect(r)}</td><td>{html.escape(proxy)}</td>"
            f"<td>{LEVEL_WORDS.get(r['tested'], 'not tested')}</td>"
            f"<td class='num'>{_p(r['p_value'])}</td><td class='num'>{drop}</td>"
            f"<td>{html.escape(r['physical_reading'])}</td></tr>")
    return "".join(rows)


def _design_section(design) -> str:
    shares = design.shares
    head = "".join(f"<th>{LEVEL_WORDS[c]}</th>" for c in shares.columns)
    body = "".join(
        f"<tr><td><code>{html.escape(name)}</code></td>"
        + "".join(f"<td class='num'>{100 * v:.0f} %</td>" for v in row)
        + "</tr>" for name, row in shares.iterrows())
    pairs = "".join(
        f"<li><b>{html.escape(' / '.join(c['inputs']))}</b>"
        + (f" (r = {c['r']:.2f})" if c["r"] is not None else "")
        + f": {html.escape(c['separating_test'])}</li>" for c in design.confounded)
    counts = design.counts
    return (f"<p>{counts['points']} points in {counts['runs']} runs, {counts['visits']} visits, "
            f"{counts['units']} machine axes. Share of each input's variance at each level: an "
            "input that varies only between visits is tested against the visits alone, and "
            "cannot be told apart from anything else that changed between them.</p>"
            f"<table><tr><th>input</th>{head}</tr>{body}</table>"
            f"<p>Confounded inputs and the test that would separate them:</p>"
            f"<ul>{pairs or '<li>none: no two inputs move together (|r| &lt; 0.7)</li>'}</ul>")


def _association_rows(t) -> str:
    from features.ranking import format_p

    rows = []
    for name, r in t.iterrows():
        cls = "" if r["influence"] else ' class="weak"'
        paper = PAPER_TABLE5.get(name)
        rows.append(
            f"<tr{cls}><td class='num'>{int(r['rank'])}</td>"
            f"<td>{html.escape(r['label'])}</td>"
            f"<td class='num'>{_pm(r['anova_score'], r['anova_score_std'], '.3f')}<br>"
            f"{html.escape(format_p(r['anova_score']))}</td>"
            f"<td class='num'>{'' if paper is None else f'{paper:.3f}'}</td>"
            f"<td class='num'>{_pm(r['permutation_um'], r['permutation_std_um'])}</td>"
            f"<td class='num'>{_pm(r['mutual_info'], r['mutual_info_std'])}<br>"
            f"noise {r['mutual_info_null']:.2g}</td>"
            f"<td class='num'>{_pm(r['knn_drop'], r['knn_drop_std'])}</td>"
            f"<td>{html.escape(r['reading'])}</td></tr>")
    return "".join(rows)


def _confusion_table(knn) -> str:
    labels = [html.escape(c) for c in knn.class_labels]
    head = "".join(f"<th>{c}</th>" for c in labels)
    body = "".join(
        f"<tr><th>{labels[i]} ({knn.class_counts[i]})</th>"
        + "".join(f"<td class='num'>{v}</td>" for v in row) + "</tr>"
        for i, row in enumerate(knn.confusion))
    return f"<table><tr><th>true \\ predicted</th>{head}</tr>{body}</table>"


def render_body(result, *, source: str = "", target_kind: str = "",
                notes: list[str] | tuple = (), unit: str = "um") -> str:
    """The report's HTML body; images are the relative PNG files of ``FILES``."""
    t = result.table
    knn = result.knn
    inf = result.influence
    folds = ", ".join(f"{100 * a:.1f}" for a in knn.fold_accuracy)
    note_items = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
    target_line = (f", backlash target <code>{html.escape(target_kind)}</code>"
                   if target_kind else "")
    derived = [n for n in ("deviation_down_um", "deviation_up_um") if n in t.index]
    derived_note = ("<p>The deviation inputs come from the same linear test the backlash "
                    "target is computed from: they predict it without causing it, and their "
                    "association scores say so.</p>" if derived else "")
    return f"""<p>Data: <code>{html.escape(source)}</code> &mdash; {result.n_points} backlash
points, {len(t)} inputs{target_line}.</p>
<div class="summary">{_headline(t, unit)}</div>

<h2>Verdicts given the other inputs</h2>
<p><b>driver</b>: a physical path to lost motion (an effect record) and a significant partial
F-test in the effect model (family-wise level {inf.alpha:g}); the effect is the peak-to-peak of
its fitted partial effect over the observed range, with a 95 % interval from {inf.n_boot}
bootstrap resamples of runs, visits or points (the level it was tested at; draws from the
coefficients' t distribution where that level has fewer than 12 cells). <b>proxy</b>: it
moves with backlash but stands in for something else (column <i>stands in for</i>).
<b>none</b>: no influence measurable given the others. An input without a physical path is
never a driver.</p>
<table>
<tr><th>input</th><th>verdict</th><th>effect [{unit}] [95 % interval]</th><th>stands in for</th>
<th>tested</th><th>p given the others</th><th>drop-column [{unit}]</th><th>physical reading</th></tr>
{_verdict_rows(t)}
</table>
<img src="{FILES['effects']}" alt="effect of each input over its observed range">

<h2>Design</h2>
{_design_section(inf.design)}

<h2>Association: the paper's views (Fig. 14, Table 5, k-NN)</h2>
<p>These scores look at one input at a time: they measure association, not influence. An input
that moves with a driver over the test plan scores like the driver.</p>
{derived_note}
<table>
<tr><th>association rank</th><th>input</th><th>ANOVA score -ln(p)</th>
<th>paper, FM38 X axis</th><th>permutation [{unit}]</th><th>mutual information [nat]</th>
<th>k-NN drop-column</th><th>association</th></tr>
{_association_rows(t)}
</table>
<p>The paper's column is the published Table 5 of a different machine, shown for scale only.
Scores grow with the number of points, so compare the order, not the values.</p>
<img src="{FILES['anova']}" alt="ANOVA score per input with bootstrap error bars">
<p>Weighted k-NN (k = {knn.n_neighbors}, weights 1/distance, standardised inputs) on
{len(knn.class_counts)} backlash classes, {knn.n_splits}-fold stratified cross-validation:
validation accuracy <b>{100 * knn.accuracy:.1f} &plusmn; {100 * knn.accuracy_std:.1f} %</b>
(folds: {folds} %; always guessing the largest class: {100 * knn.majority_rate:.1f} %).
The paper reports 98.8 %.</p>
<img src="{FILES['confusion']}" alt="k-NN confusion matrix">
{_confusion_table(knn)}
<img src="{FILES['views']}" alt="permutation importance, mutual information, k-NN loss and drop-column importance">

<h2>Method</h2>
<ul>
<li><b>Effect model</b>: each input as Legendre polynomials (degree by BIC) in a least-squares
model per stratum of the design (within runs with run fixed effects, between runs with visit
fixed effects, between visits with machine-axis fixed effects); an input is tested in every
stratum that holds at least 10 % of its variance, against that stratum's error, and its p-value
is the smallest over those strata times their number.</li>
<li><b>Physical paths</b> come from the effect records: the inputs of the lost-motion effects,
and operating hours through wear.</li>
<li><b>Drop-column importance</b>: gradient boosting, cross-validation grouped by visit (or
run), increase of the held-out RMSE when the input is left out.</li>
<li><b>Association</b>: ANOVA -ln(p) across backlash classes (log survival function, so tiny p
stays finite; &plusmn; bootstrap std); permutation importance ({html.escape(
    result.ranking.permutation_model)}); mutual information (&plusmn; std over 80 %
subsamples, noise level = mean + 3 std with backlash shuffled); k-NN drop-column loss.</li>
</ul>
{f"<h2>Notes</h2><ul>{note_items}</ul>" if note_items else ""}
"""
