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
from pathlib import Path

import pandas as pd

from features.iso230 import ENVIRONMENT, TEST_COLUMNS
from features.readings import schema
from features.readings.fileio import atomic_path
from pipeline.reports.iso_chart import draw_readings, draw_test
from pipeline.reports.report_page import new_figure, write_page

FILES = {"html": "iso_report.html", "pdf": "iso_report.pdf"}
TARGET_COLUMNS = ("target", "n_up", "n_down", "mean_up", "mean_down", "s_up", "s_down", "B_i",
                  "R_i")
A4_IN = (8.27, 11.69)
# Labels and units of the conditions a readings file may hold (schema.md, section 1).
LABELS = {"machine_id": "machine", "axis": "axis", "visit": "visit", "test_id": "test",
          "method": "method", "repeat": "repeat", "feed_mm_min": "feed [mm/min]",
          "dwell_s": "dwell [s]", "started_at": "started", "operating_hours": "operating hours [h]",
          "machine_temp_c": "machine temperature [°C]", "ambient_temp_c": "air temperature [°C]",
          "pressure_hpa": "air pressure [hPa]", "humidity_pct": "humidity [%RH]"}


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
    pairs.append(("instrument", str(row["instrument"]) if pd.notna(row.get("instrument"))
                  else "not recorded in the readings"))
    return pairs


def figure_lines(row: pd.Series, keys: tuple[str, ...]) -> list[tuple[str, str]]:
    """(figure, value) pairs with three decimals, ``± U`` where the figures carry ``U_*_um``."""
    out = []
    for key in keys:
        u = row.get(f"U_{key}_um")
        text = f"{row[key]:.3f}" + (f" ± {u:.3f}" if u is not None and pd.notna(u) else "")
        out.append((key, text))
    return out


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


def test_figure(result, row, targets, readings, flags, source):
    """One A4 page: title and conditions, chart with every reading, B_i, per-target table."""
    # fixed margins: constrained layout costs a second per page, and every page is alike
    fig = new_figure(*A4_IN, fixed_margins=True)
    grid = fig.add_gridspec(4, 1, height_ratios=[1.5, 3.2, 1.0, 2.4], left=0.14, right=0.74,
                            hspace=0.3)  # left: room for wide tick labels and the y labels
    head, ax, ax_b, ax_t = (fig.add_subplot(grid[i]) for i in range(4))
    ax_b.sharex(ax)
    head.axis("off")
    unit = row["unit"]
    lines = [f"{result.standard.title} positioning test — {row['machine_id']} axis {row['axis']}"]
    pairs = conditions(row, source)
    lines += ["   ".join(f"{k}: {v}" for k, v in pairs[i:i + 3]) for i in range(0, len(pairs), 3)]
    lines.append("   ".join(f"{k} {v}" for k, v in figure_lines(row, ("A", "E", "M", "R", "B")))
                 + f"   [{unit}]")
    head.text(0, 1, lines[0], va="top", fontsize=11, weight="bold")
    head.text(0, 0.78, "\n".join(lines[1:]), va="top", fontsize=7.5, family="monospace")
    draw_readings(ax, readings, flags)
    draw_test(ax, ax_b, targets, row)
    ax_t.axis("off")
    cells = [[f"{v:g}" if c.startswith("n_") or c == "target" else f"{v:.3f}"
              for c, v in zip(TARGET_COLUMNS, r)] for r in targets[list(TARGET_COLUMNS)]
             .itertuples(index=False)]
    table = ax_t.table(cellText=cells, colLabels=[f"{c}" for c in TARGET_COLUMNS],
                       loc="upper center")
    table.auto_set_font_size(False)
    table.set_fontsize(7)
    ax_t.set_title(f"per target [{unit}; targets in {schema.position_unit(row['axis'])}]",
                   fontsize=8)
    return fig


def render_body(result, charts: list[bytes]) -> str:
    """The HTML body: the standard, then per test its conditions, figures, table and chart."""
    parts = [(f'<p class="summary">Standard: <b>{html.escape(result.standard.title)}</b>; '
              f'{len(result.figures)} test(s); outliers '
              f'{"left out of" if result.dropped else "kept in"} the figures and ringed on the '
              "charts.</p>")]
    for (row, targets, _, _, source), png in zip(_pages(result), charts):
        title = f"{row['machine_id']} axis {row['axis']} visit {row['visit']} — {row['test_id']}"
        cond = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                       for k, v in conditions(row, source))
        figs = "".join(f'<tr><th>{k}</th><td class="num">{v}</td></tr>'
                       for k, v in figure_lines(row, result.standard.figures))
        head = "".join(f"<th>{c}</th>" for c in TARGET_COLUMNS)
        body = "".join("<tr>" + "".join(f'<td class="num">{v:.3f}</td>' for v in r) + "</tr>"
                       for r in targets[list(TARGET_COLUMNS)].itertuples(index=False))
        image = base64.b64encode(png).decode("ascii")
        parts.append(
            f"<h2>{html.escape(title)}</h2>\n<h3>Conditions</h3><table>{cond}</table>\n"
            f"<h3>Axis figures [{row['unit']}]</h3><table>{figs}</table>\n"
            f"<h3>Per target</h3><table><tr>{head}</tr>{body}</table>\n"
            f'<p><img src="data:image/png;base64,{image}" alt="chart of {html.escape(title)}">'
            "</p>")
    return "\n".join(parts)


# The HTML shows each page as an image at screen resolution: half the pixels of the print dpi.
PNG_DPI = 80


def write_report(result, out) -> dict[str, Path]:
    """Write ``iso_report.pdf`` (one A4 page per test) and ``iso_report.html`` into ``out``.

    Parameters
    ----------
    result : pipeline.steps.iso.IsoResult
        The figures, readings and outliers of the tests.
    out : str or path-like
        The folder (created if needed); both files are written atomically.
    """
    from matplotlib.backends.backend_pdf import PdfPages

    out = Path(out)
    paths = {role: out / name for role, name in FILES.items()}
    charts = []
    with atomic_path(paths["pdf"]) as tmp, PdfPages(tmp, metadata={
            "Title": f"Positioning test report ({result.standard.title})",
            "Subject": ", ".join(result.figures["test_id"].astype(str))}) as pdf:
        for page in _pages(result):
            fig = test_figure(result, *page)
            pdf.savefig(fig)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=PNG_DPI)
            charts.append(buffer.getvalue())
    write_page(paths["html"], f"Positioning test report ({result.standard.title})",
               render_body(result, charts))
    return paths
