"""The printable test report of ISO positioning tests: one page per test, as HTML and PDF.

Each page names the standard, gives the test conditions the readings file holds, the axis
figures (with their expanded uncertainty when a budget was given), the per-target table
(means, s, B_i, R_i) and the chart with every reading and the flagged outliers marked. The PDF
is matplotlib's PDF backend (``PdfPages``), one A4 page per test; the HTML is the one page
shell of ``pipeline.reports.report_page`` with the same charts embedded.
"""

from __future__ import annotations

import base64
import html
import io
import textwrap
from pathlib import Path

import pandas as pd

from features import iso230
from features.iso230 import ENVIRONMENT, TEST_COLUMNS
from features.readings import schema
from features.readings.fileio import atomic_path
from pipeline.reports.iso_chart import (
    SYMBOLS,
    below_uncertainty,
    display_unit,
    draw_readings,
    draw_test,
)
from pipeline.reports.report_page import new_figure, write_page

FILES = {"html": "iso_report.html", "pdf": "iso_report.pdf"}
TARGET_COLUMNS = ("target", "n_up", "n_down", "mean_up", "mean_down", "s_up", "s_down", "B_i",
                  "R_i")
# ISO 230-2:2014 symbols of the per-target columns (i: the target position's index; arrows:
# the direction of approach), as the PDF (Unicode: mathtext costs a second a report) and the
# HTML print them.
TARGET_SYMBOLS = {"target": ("Pᵢ", "P<sub>i</sub>"), "n_up": ("nᵢ↑", "n<sub>i</sub>↑"),
                  "n_down": ("nᵢ↓", "n<sub>i</sub>↓"), "mean_up": ("x̄ᵢ↑", "x̄<sub>i</sub>↑"),
                  "mean_down": ("x̄ᵢ↓", "x̄<sub>i</sub>↓"), "s_up": ("sᵢ↑", "s<sub>i</sub>↑"),
                  "s_down": ("sᵢ↓", "s<sub>i</sub>↓"), "B_i": ("Bᵢ", "B<sub>i</sub>"),
                  "R_i": ("Rᵢ", "R<sub>i</sub>")}
A4_IN = (8.27, 11.69)
FOOT_IN = 2.15  # the remarks and the signature block at the foot of every page [in]
# Labels and units of the conditions a readings file may hold (schema.md, section 1).
LABELS = {"machine_id": "machine", "axis": "axis", "visit": "visit", "test_id": "test",
          "method": "method", "repeat": "repeat", "feed_mm_min": "feed [mm/min]",
          "dwell_s": "dwell [s]", "started_at": "started", "operating_hours": "operating hours [h]",
          "machine_temp_c": "machine temperature [°C]", "ambient_temp_c": "air temperature [°C]",
          "pressure_hpa": "air pressure [hPa]", "humidity_pct": "humidity [%RH]"}
OUTLIER_RULE = (f"outliers: the product's rule, not ISO 230-2's: a reading more than "
                f"{iso230.OUTLIER_THRESHOLD:g} robust scale units (1.4826 MAD of its siblings, "
                "at least the test's s) from the median of its siblings")
SIGNATURE = "signature: ______________________________   date: ________________"


def conditions(row: pd.Series, source: str) -> list[tuple[str, str]]:
    """The test's conditions as (label, value) pairs: its file, keys, carried test columns and
    environment means, those the file holds; the instrument is named only when recorded."""
    pairs = [("file", source)]
    for key in (*schema.TEST_KEYS, *TEST_COLUMNS, *ENVIRONMENT):
        value = row.get(key)
        if value is not None and pd.notna(value):
            label = LABELS[key]
            if key == "feed_mm_min" and schema.is_rotary(row["axis"]):
                label = "feed [deg/min]"  # a rotary axis's feed_mm_min holds deg/min
            pairs.append((label, f"{value:.2f}" if isinstance(value, float) else str(value)))
    if pd.notna(row.get("instrument")):
        pairs.append(("instrument in the readings", str(row["instrument"])))
    return pairs


def signing(meta) -> list[tuple[str, str]]:
    """(label, value) of who tested with what (``pipeline.reports.report_meta``), or the lines a
    page without ``--meta`` leaves to be filled in by hand."""
    if meta is None:
        return [("operator", "not given (--meta)"), ("instrument", "not given (--meta)")]
    return meta.pairs()


def uncertainty_line(result) -> str:
    """What U is: the coverage factor, the budget's name and digest; or that there is none."""
    budget = result.budget
    if budget is None:
        return "uncertainty: no budget given (--uncertainty): figures without U"
    name = budget.name or "budget given in code"
    return (f"U: expanded uncertainty, k = {budget.coverage_factor:g} (ISO/TR 230-9), at the "
            f"test's measuring length; budget \"{name}\", digest {budget.digest()}")


def figure_lines(row: pd.Series, keys) -> list[tuple[str, str]]:
    """(ISO 230-2 symbol, value) pairs with three decimals, ``± U`` where the figures carry
    ``U_*_um``, marked ``*`` where the figure is smaller than its U."""
    out = []
    for key in keys:
        u = row.get(f"U_{key}_um")
        text = f"{row[key]:.3f}"
        if u is not None and pd.notna(u):
            text += f" ± {u:.3f}" + (" *" if below_uncertainty(row, key) else "")
        out.append((SYMBOLS.get(key, key), text))
    return out


def target_cells(targets: pd.DataFrame) -> list[list[str]]:
    """The per-target table's cells: counts as integers, targets as written, the rest with
    three decimals."""
    rows = []
    for r in targets[list(TARGET_COLUMNS)].itertuples(index=False):
        rows.append([f"{int(v)}" if c.startswith("n_") else f"{v:g}" if c == "target"
                     else f"{v:.3f}" for c, v in zip(TARGET_COLUMNS, r)])
    return rows


def _pages(result):
    """(figures row, its targets, its readings, its outlier flags, its source) per test."""
    keys = list(schema.TEST_KEYS)
    flags = pd.Series(False, index=result.readings.index)
    flags.loc[result.outliers.index] = True
    by_test = {k: g for k, g in result.readings.groupby(keys, sort=False)}
    targets = {k: g for k, g in result.targets.groupby(keys, sort=False)}
    for _, row in result.figures.iterrows():
        key = tuple(row[k] for k in keys)
        readings = by_test[key]
        yield row, targets[key].sort_values("target"), readings, flags.loc[readings.index], \
            result.sources.get(key, "readings")


def header_lines(result, row, source, flags, meta) -> list[str]:
    """The page's text above the chart: conditions, who tested with what, what U is and the
    outlier rule."""
    def rows_of(pairs, per_line):
        return ["   ".join(f"{k}: {v}" for k, v in pairs[i:i + per_line])
                for i in range(0, len(pairs), per_line)]

    lines = rows_of(conditions(row, source), 3) + [""]
    who = signing(meta)
    sensors = [v for k, v in who if k == "environment sensor"]
    named = [p for p in who if p[0] != "environment sensor"]
    # who; the instrument alone (its names are long); its serial and calibration
    lines += rows_of(named[:2], 2) + rows_of(named[2:3], 1) + rows_of(named[3:], 2)
    lines += [f"environment sensor: {v}" for v in sensors] + [""]
    lines.append(uncertainty_line(result))
    state = "left out of" if result.dropped else "kept in"
    lines.append(f"{int(flags.sum())} outlier(s) ringed on the chart, {state} the figures; "
                 + OUTLIER_RULE)
    return lines


def _band(fig, left: float, width: float, top_in: float, height_in: float):
    """Axes ``height_in`` [in] high whose top lies ``top_in`` [in] below the page's top, from
    ``left`` over ``width`` (fractions of the page's width)."""
    page = fig.get_size_inches()[1]
    return fig.add_axes((left, 1 - (top_in + height_in) / page, width, height_in / page))


def test_figure(result, row, targets, readings, flags, source, meta=None):
    """One A4 page: title and conditions, who tested with what and U, the chart with every
    reading and the axis figures, B_i, the per-target table, remarks and the signature block.

    The bands are placed from the top in inches (their heights are known), so the page has no
    gap under its header and the table's ISO 230-2 symbols fit their columns."""
    # fixed margins: constrained layout costs a second per page, and every page is alike
    fig = new_figure(*A4_IN, fixed_margins=True)
    left, width = 0.11, 0.62  # of the page: room for wide tick labels, the figures box right
    unit = display_unit(row["unit"])
    fig.text(0.06, 1 - 0.45 / A4_IN[1], f"{result.standard.title} positioning test — "
             f"{row['machine_id']}, axis {row['axis']}", fontsize=11, weight="bold")
    lines = [textwrap.fill(t, 118) if t else t for t in header_lines(result, row, source,
                                                                     flags, meta)]
    fig.text(0.06, 1 - 0.65 / A4_IN[1], "\n".join(lines), va="top", fontsize=6.6,
             family="monospace", linespacing=1.25)
    # 6.6 pt at 1.25 spacing is 0.115 in a line: 0.125 leaves room, then a gap for the title
    top = 0.65 + sum(t.count("\n") + 1 for t in lines) * 0.125 + 0.35
    # the chart takes what the header, the table's rows of 0.2 in and the foot leave (a long
    # list of sensors or targets shrinks it, down to 1.5 in)
    chart_in = min(3.3, max(1.5, A4_IN[1] - FOOT_IN - top - 1.8 - 0.2 * (len(targets) + 1)))
    ax = _band(fig, left, width, top, chart_in)
    ax_b = _band(fig, left, width, top + chart_in + 0.15, 0.9)
    ax_b.sharex(ax)
    ax.tick_params(labelbottom=False)
    draw_readings(ax, readings, flags)
    draw_test(ax, ax_b, targets, row,
              None if result.budget is None else result.budget.coverage_factor)
    table_top = top + chart_in + 0.15 + 0.9 + 0.75
    # rows of 0.2 in, narrower for a long table: it ends above the signature block
    row_in = max(0.05, min(0.2, (A4_IN[1] - FOOT_IN - table_top) / (len(targets) + 1)))
    ax_t = _band(fig, 0.06, 0.88, table_top, row_in * (len(targets) + 1))
    ax_t.axis("off")
    table = ax_t.table(cellText=target_cells(targets),
                       colLabels=[TARGET_SYMBOLS[c][0] for c in TARGET_COLUMNS],
                       loc="upper center", cellLoc="right", bbox=[0, 0, 1, 1])
    table.auto_set_font_size(False)
    table.set_fontsize(7.5 if row_in >= 0.15 else 5.5)
    fig.text(0.06, 1 - (table_top - 0.08) / A4_IN[1],
             f"per target position Pᵢ [{schema.position_unit(row['axis'])}]; deviations "
             f"[{unit}]; ↑ moving +, ↓ moving −", fontsize=8)
    fig.text(0.06, 0.6 / A4_IN[1], _closing(meta, result.budget, unit), fontsize=7.5, va="bottom",
             family="monospace", linespacing=1.6)
    return fig


def _closing(meta, budget, unit: str) -> str:
    """Remarks, the mark's meaning and the signature block at the foot of every page."""
    lines = []
    if meta is not None and meta.remarks:
        lines += textwrap.wrap(f"remarks: {meta.remarks}", 110)
    if budget is not None:
        lines.append(f"* a figure smaller than its expanded uncertainty U [{unit}]: the "
                     "measurement cannot tell it from 0")
    operator = meta.operator if meta is not None else "______________________________"
    lines += ["", f"tested by: {operator}", SIGNATURE, "", ("approved by: "
              "______________________________"), SIGNATURE]
    return "\n".join(lines)


def render_body(result, charts: list[bytes], meta=None) -> str:
    """The HTML body: the standard, then per test its conditions, who tested with what, the
    figures (± U, with k and the budget), the table, the chart, and the signature block."""
    parts = [(f'<p class="summary">Standard: <b>{html.escape(result.standard.title)}</b>; '
              f'{len(result.figures)} test(s); outliers '
              f'{"left out of" if result.dropped else "kept in"} the figures and ringed on the '
              f"charts. {html.escape(uncertainty_line(result))}.<br>"
              f"{html.escape(OUTLIER_RULE)}.</p>")]
    unit_rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                        for k, v in signing(meta))
    remarks = (f"<p>Remarks: {html.escape(meta.remarks)}</p>" if meta is not None
               and meta.remarks else "")
    operator = html.escape(meta.operator) if meta is not None else "&nbsp;" * 30
    sign = (f'<table><tr><th>tested by</th><td>{operator}</td><th>signature</th>'
            '<td style="width:14em"></td><th>date</th><td style="width:8em"></td></tr>'
            '<tr><th>approved by</th><td></td><th>signature</th><td></td><th>date</th><td></td>'
            "</tr></table>")
    mark = ("<p>* smaller than its expanded uncertainty U: not told from 0.</p>\n"
            if result.budget is not None else "")
    for (row, targets, _, _, source), png in zip(_pages(result), charts):
        unit = display_unit(row["unit"])
        title = f"{row['machine_id']} axis {row['axis']} visit {row['visit']} — {row['test_id']}"
        cond = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                       for k, v in conditions(row, source))
        figs = "".join(f'<tr><th>{k}</th><td class="num">{v}</td></tr>'
                       for k, v in figure_lines(row, result.standard.figures))
        head = "".join(f"<th>{TARGET_SYMBOLS[c][1]}</th>" for c in TARGET_COLUMNS)
        body = "".join("<tr>" + "".join(f'<td class="num">{v}</td>' for v in r) + "</tr>"
                       for r in target_cells(targets))
        image = base64.b64encode(png).decode("ascii")
        parts.append(
            f"<h2>{html.escape(title)}</h2>\n<h3>Conditions</h3><table>{cond}</table>\n"
            f"<h3>Tested with</h3><table>{unit_rows}</table>\n"
            f"<h3>Axis figures [{unit}]</h3><table>{figs}</table>\n{mark}"
            f"<h3>Per target [{unit}; P<sub>i</sub> in {schema.position_unit(row['axis'])}]"
            f"</h3><table><tr>{head}</tr>{body}</table>\n"
            f'<p><img src="data:image/png;base64,{image}" alt="page of {html.escape(title)}">'
            f"</p>\n{remarks}{sign}")
    return "\n".join(parts)


# The HTML shows each page as an image at screen resolution: half the pixels of the print dpi.
PNG_DPI = 80


def write_report(result, out, meta=None) -> dict[str, Path]:
    """Write ``iso_report.pdf`` (one A4 page per test) and ``iso_report.html`` into ``out``.

    Parameters
    ----------
    result : pipeline.steps.iso.IsoFigures
        The figures, readings and outliers of the tests.
    out : str or path-like
        The folder (created if needed); both files are written atomically.
    meta : pipeline.reports.report_meta.ReportMeta, optional
        Who tested with what, printed on every page.
    """
    from matplotlib.backends.backend_pdf import PdfPages

    out = Path(out)
    paths = {role: out / name for role, name in FILES.items()}
    charts = []
    info = {"Title": f"Positioning test report ({result.standard.title})",
            "Subject": ", ".join(result.figures["test_id"].astype(str))}
    if meta is not None:
        info["Author"] = meta.operator
    with atomic_path(paths["pdf"]) as tmp, PdfPages(tmp, metadata=info) as pdf:
        for page in _pages(result):
            fig = test_figure(result, *page, meta=meta)
            pdf.savefig(fig)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=PNG_DPI)
            charts.append(buffer.getvalue())
    write_page(paths["html"], f"Positioning test report ({result.standard.title})",
               render_body(result, charts, meta))
    return paths
