"""``backlash report``: the printable test report (PDF and HTML) of the real ecmc tests,
checked page by page against the hand calculation of the files."""

from __future__ import annotations

import re
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

from features import iso230
from features.readings import read_readings
from pipeline.cli import main
from pipeline.reports import iso_report
from pipeline.reports.iso_chart import DOWN, OUTLIER_LABEL, UP, draw_readings
from pipeline.reports.report_page import new_figure
from pipeline.workflows.report import report
from tests.test_iso230 import hand_calculation, synthetic

ROOT = Path(__file__).resolve().parents[1]
BUDGET = ROOT / "experiments" / "data" / "paper_uncertainty.toml"
pytestmark = pytest.mark.filterwarnings("ignore::features.readings.errors.BacklashWarning")


def pdf_pages(path: Path) -> list[str]:
    """The text of each page of a matplotlib PDF: its page objects counted, the strings of
    the text objects of its content streams joined (no PDF library is installed)."""
    data = path.read_bytes()
    assert data[:5] == b"%PDF-"
    n_pages = len(re.findall(rb"/Type\s*/Page\b", data))
    texts = []
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", data, re.DOTALL):
        try:  # a stream whose last byte is CR loses it to the pattern: only its checksum is cut
            body = zlib.decompressobj().decompress(m.group(1))
        except zlib.error:  # fonts and images
            continue
        blocks = re.findall(rb"BT(.*?)ET", body, re.DOTALL)
        if blocks:
            texts.append("\n".join(_unescape(b"".join(re.findall(rb"\(((?:\\.|[^\\)])*)\)", b)))
                                   for b in blocks))
    assert len(texts) == n_pages
    return texts


def _unescape(text: bytes) -> str:
    """A PDF string's escaped parentheses and backslashes as themselves."""
    return re.sub(rb"\\([()\\])", rb"\1", text).decode("latin-1")


def test_two_files_give_two_pages_with_hand_figures(ess_file, psi_file, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", str(ess_file), str(psi_file), "--out", str(out),
                 "--uncertainty", str(BUDGET)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["iso_report.html", "iso_report.pdf"]
    pages = pdf_pages(out / "iso_report.pdf")
    html = (out / "iso_report.html").read_text(encoding="utf-8")
    for page, path in zip(pages, (ess_file, psi_file)):
        want = hand_calculation(path)
        assert "ISO 230-2:2014 positioning test" in page and str(path) in page
        assert "operator: not given (--meta)" in page and "tested by: ____" in page
        for key in ("A", "E", "M", "R", "B", "B_mean"):
            assert f"{want[key]:.3f}" in page and f"{want[key]:.3f}" in html, key
        for row in want["per_target"]:
            for key in ("mean_up", "mean_down", "s_up", "s_down", "B_i", "R_i"):
                assert f"{row[key]:.3f}" in page, (path.name, row["target"], key)
    # the ESS page: figures ± U (hand values of tests/test_iso_uncertainty.py), outliers ringed
    assert "B     43.459 ± 4.115" in pages[0] and "outlier (8-MAD rule)" in pages[0]
    assert "U: expanded uncertainty, k = 2" in pages[0] and "not ISO 230-2's" in pages[0]
    assert "93.2" in pages[0] and "62.8" in pages[0] and "93.2" not in pages[1]
    assert html.count("<h2>") == 2 and html.count("data:image/png;base64,") == 2
    assert "Standard: <b>ISO 230-2:2014</b>" in html


def test_the_chart_rings_exactly_the_flagged_readings(ess_file):
    readings = read_readings(ess_file)
    _, ax = new_figure(4, 3, nrows=1, ncols=1)
    draw_readings(ax, readings, iso230.outliers(readings))
    (ring,) = [line for line in ax.lines if line.get_label() == OUTLIER_LABEL]
    assert sorted(round(v, 1) for v in ring.get_ydata()) == [62.8, 93.2]
    dots = sum(len(line.get_ydata()) for line in ax.lines if line.get_label().startswith("read"))
    assert dots == len(readings) == 50


def test_any_number_of_tests_one_page_each(tmp_path, capsys):
    many = tmp_path / "many.csv"
    synthetic(13, seed=4).to_csv(many, index=False)  # more than the iso chart's 12 panels
    assert main(["report", str(many), "--out", str(tmp_path / "out")]) == 0
    pages = pdf_pages(tmp_path / "out" / "iso_report.pdf")
    assert len(pages) == 13 and all("positioning test" in p for p in pages)
    assert [re.search(r"test: (T\d+)", p).group(1) for p in pages] == [f"T{i}" for i in range(13)]


@pytest.mark.parametrize("args, words", [
    (["missing.dat"], "no such file"),
    (["bad.csv"], "unknown format"),
    (["{ess}", "--standard", "vdi3441"], "VDI/DGQ 3441:1982 is not supported"),
    (["{ess}", "--standard", "nmtba"], "invalid choice: 'nmtba'"),
])
def test_bad_input_is_one_line_and_writes_nothing(ess_file, tmp_path, capsys, args, words):
    (tmp_path / "bad.csv").write_text("machine_id,axis,test_id\nM,X,T\n")
    args = [str(ess_file) if a == "{ess}" else str(tmp_path / a) if a.endswith(
        (".dat", ".csv")) else a for a in args]
    out = tmp_path / "report"
    assert main(["report", *args, "--out", str(out), "--json"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert captured.out == "" and not out.exists()


RENDER_DPI = 100
RING = ("black", 9.0)  # how draw_readings rings a flagged reading: edge colour, size [pt]


def rendered_pages(pdf: Path, dpi: int = RENDER_DPI) -> list[np.ndarray]:
    """Each page of ``pdf`` as poppler draws it: an RGB array in [0, 1], top row first."""
    from matplotlib.image import imread

    subprocess.run(["pdftoppm", "-r", str(dpi), "-png", str(pdf), str(pdf.with_suffix(""))],
                   check=True, capture_output=True, timeout=120)
    pngs = sorted(pdf.parent.glob(f"{pdf.stem}-*.png"), key=lambda p: int(p.stem.split("-")[-1]))
    return [imread(png)[..., :3] for png in pngs]


def _near(pixels: np.ndarray, colour: str, tol: float) -> np.ndarray:
    from matplotlib.colors import to_rgb

    return np.abs(pixels - np.array(to_rgb(colour))).max(axis=-1) <= tol


def ringed(img: np.ndarray, x: float, y: float, radius: float, colour: str) -> float:
    """The share of 32 directions around pixel (x, y) (from the top left) in which a pixel of
    ``colour`` lies within a pixel of ``radius``: near 1 inside a ring, low elsewhere."""
    angles = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    hits = np.zeros(len(angles), dtype=bool)
    for r in (radius - 1, radius, radius + 1):
        cols = np.floor(x + r * np.cos(angles)).astype(int)
        rows = np.floor(y + r * np.sin(angles)).astype(int)
        hits |= _near(img[rows, cols], colour, 0.35)
    return hits.mean()


@pytest.mark.pdftoppm
@pytest.mark.skipif(shutil.which("pdftoppm") is None,
                    reason="pdftoppm not found (apt-get install poppler-utils)")
def test_the_pdf_pages_as_drawn_hold_the_charts(ess_file, psi_file, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", str(ess_file), str(psi_file), "--out", str(out),
                 "--uncertainty", str(BUDGET)]) == 0
    images = rendered_pages(out / "iso_report.pdf")
    # the same pages, laid out again to know where each reading is drawn
    result = report([str(ess_file), str(psi_file)], uncertainty=str(BUDGET)).iso
    assert len(images) == len(result.figures) == 2
    rings = []
    for img, page in zip(images, iso_report._pages(result)):
        fig = iso_report.test_figure(result, *page)
        width_in, height_in = fig.get_size_inches()
        assert abs(width_in * 25.4 - 210) < 1 and abs(height_in * 25.4 - 297) < 1  # A4
        assert abs(img.shape[1] - width_in * RENDER_DPI) <= 2
        assert abs(img.shape[0] - height_in * RENDER_DPI) <= 2
        assert (img.min(axis=-1) < 0.9).mean() > 0.04  # text, table and chart, not a blank page
        (ax,) = [a for a in fig.axes if any(line.get_label() == "readings +" for line in a.lines)]
        scale = RENDER_DPI / fig.dpi  # figure pixels to rendered pixels
        box, height = ax.get_window_extent(), fig.bbox.height
        chart = img[int((height - box.y1) * scale):int((height - box.y0) * scale),
                    int(box.x0 * scale):int(box.x1 * scale)]
        for colour in (UP, DOWN):  # the mean lines and their markers, up and down, in the chart
            assert _near(chart, colour, 0.06).sum() > 300, colour
            assert _near(chart, colour, 0.06).sum() == _near(img, colour, 0.06).sum(), colour
        # every reading where the page puts it: is there a ring around it in the drawn page?
        readings = np.vstack([line.get_xydata() for line in ax.lines
                              if line.get_label().startswith("readings")])
        assert len(readings) == len(page[2]) == 50
        radius = RING[1] / 2 / 72 * RENDER_DPI
        found = []
        for (target, deviation), (x, y) in zip(readings, ax.transData.transform(readings)):
            share = ringed(img, x * scale, (height - y) * scale, radius, RING[0])
            assert share > 0.9 or share < 0.5, (target, deviation, share)  # ring or clearly none
            if share > 0.9:
                found.append(round(deviation, 1))
        flagged = page[2].loc[page[3], "deviation_um"]
        assert sorted(found) == sorted(round(v, 1) for v in flagged)
        rings.append(sorted(found))
    # the two readings the outlier rule flags on the ESS file, none on the PSI file
    assert rings == [[62.8, 93.2], []]
    for img, page in zip(images, iso_report._pages(result)):
        # no blank band under the header: between the title and the chart, no run of white
        # rows taller than half an inch (the pages had 1.1 in)
        fig = iso_report.test_figure(result, *page)
        (ax,) = [a for a in fig.axes if any(line.get_label() == "readings +" for line in a.lines)]
        scale = RENDER_DPI / fig.dpi
        chart_top = int((fig.bbox.height - ax.get_window_extent().y1) * scale)
        inked = (img[:chart_top].min(axis=-1) < 0.8).any(axis=1)
        rows = np.flatnonzero(inked)
        assert np.diff(rows).max() < 0.5 * RENDER_DPI, np.diff(rows).max() / RENDER_DPI
        # the signature block is drawn in the page's last 2 in: its lines are ink
        foot = img[-2 * RENDER_DPI:]
        assert ((foot.min(axis=-1) < 0.5).sum(axis=1) > 0.2 * img.shape[1]).sum() >= 2


def test_every_table_label_fits_its_cell(ess_file):
    """The per-target table's ISO 230-2 symbols and numbers lie inside their cells (the
    "mean_down" header was clipped)."""
    result = report(str(ess_file), uncertainty=str(BUDGET)).iso
    fig = iso_report.test_figure(result, *next(iso_report._pages(result)))
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    [table] = [t for a in fig.axes for t in a.tables]
    cells = table.get_celld()
    assert len(cells) == 6 * 9  # header and 5 targets, 9 columns
    for cell in cells.values():
        box, text = cell.get_window_extent(renderer), cell.get_text().get_window_extent(renderer)
        assert box.x0 <= text.x0 and text.x1 <= box.x1, cell.get_text().get_text()


# --------------------------------------------------------------------------- a page one signs
META = """[report]
operator = "A. Sandström"
organisation = "European Spallation Source ERIC"
instrument = "Renishaw XL-80 laser interferometer"
instrument_serial = "XL80-123456"
instrument_calibrated_on = 2026-02-10
remarks = "Axis at 21.3 °C after 2 h warm-up."

[[report.sensors]]
name = "air temperature"
serial = "XC80-T-998"
calibrated_on = 2026-01-15
"""


def _flat(text: str) -> str:
    """Text with its line breaks and runs of spaces as one space (wrapped lines joined)."""
    return " ".join(text.split())


def test_the_page_names_who_tested_with_what_and_what_u_is(ess_file, psi_file, tmp_path, capsys):
    meta = tmp_path / "meta.toml"
    meta.write_text(META, encoding="utf-8")
    out = tmp_path / "report"
    assert main(["report", str(ess_file), str(psi_file), "--out", str(out), "--uncertainty",
                 str(BUDGET), "--meta", str(meta)]) == 0
    html = _flat((out / "iso_report.html").read_text(encoding="utf-8"))
    from features.uncertainty import read_budget

    budget = read_budget(BUDGET)
    for page in map(_flat, pdf_pages(out / "iso_report.pdf")):  # every page, the same block
        for words in ("operator: A. Sandström", "organisation: European Spallation Source ERIC",
                      "instrument: Renishaw XL-80 laser interferometer", "serial no.: XL80-123456",
                      "calibrated on: 2026-02-10", ("air temperature (serial XC80-T-998), "
                      "calibrated on 2026-01-15"), "remarks: Axis at 21.3 °C after 2 h warm-up.",
                      "tested by: A. Sandström", "approved by: ____", "signature: ____",
                      "date: ____", "U: expanded uncertainty, k = 2",
                      f'budget "{budget.name}", digest {budget.digest()}',
                      "ISO 230-2 [µm] ± U (k = 2)"):
            assert words in page, words
        # one spelling of the micrometre; ISO symbols, not column names, head the table
        assert "[um]" not in page and "mean_up" not in page and "s_down" not in page
    assert "FM38 X axis, HP 5500C laser (backlash paper, Table 3)" in budget.name
    for words in ("A. Sandström", "XL80-123456", "2026-02-10", "k = 2", budget.digest(),
                  "x̄<sub>i</sub>↑", "approved by"):
        assert words in html, words
    assert "mean_up" not in html and "5.000" not in html  # counts are integers: 5


def test_a_figure_smaller_than_its_uncertainty_is_marked(ess_file, psi_file, tmp_path, capsys):
    """PSI: A = 0.089 um against U(A) of several um (tests/test_iso230.py's hand figures);
    ESS: every figure well above its U, none marked."""
    out = tmp_path / "report"
    assert main(["report", str(ess_file), str(psi_file), "--out", str(out), "--uncertainty",
                 str(BUDGET)]) == 0
    pages = pdf_pages(out / "iso_report.pdf")
    result = report([str(ess_file), str(psi_file)], uncertainty=str(BUDGET)).iso
    for page, (_, row) in zip(pages, result.figures.iterrows()):
        for key, symbol in (("A", "A"), ("E", "E"), ("M", "M"), ("R", "R"), ("B", "B")):
            line = f"{symbol:<3}{row[key]:9.3f} ± {row[f'U_{key}_um']:.3f}"
            small = abs(row[key]) < row[f"U_{key}_um"]
            assert (line + " *" in page) == small and line in page, (row["test_id"], key)
    psi = hand_calculation(psi_file)
    assert f"A  {psi['A']:9.3f} ± " in pages[1] and psi["A"] < 1.0
    assert "* smaller than its U" in pages[1] and "* smaller than its U" not in pages[0]


def test_a_budget_of_another_axis_is_refused(ess_file, tmp_path, capsys):
    budget = tmp_path / "y.toml"
    budget.write_text(BUDGET.read_text(encoding="utf-8").replace('axis = "X"', 'axis = "Y"'),
                      encoding="utf-8")
    out = tmp_path / "report"
    assert main(["report", str(ess_file), "--out", str(out), "--uncertainty", str(budget)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--uncertainty" in err[0], err
    assert "the budget is written for axis Y; test ess_mcu1025_ISO230 is of axis X" in err[0]
    assert not out.exists()
    # named by --axis, the same test is a Y test: the Y budget applies
    assert main(["report", str(ess_file), "--axis", "Y", "--out", str(out), "--uncertainty",
                 str(budget)]) == 0


@pytest.mark.parametrize("edit, words", [
    (("operator = ", "operater = "), "unknown key 'report.operater'"),
    (('operator = "A. Sandström"\n', ""), "missing key 'report.operator'"),
    (("2026-02-10", '"10.02.2026"'), ("'report.instrument_calibrated_on': expected a date "
                                     "(YYYY-MM-DD), got '10.02.2026'")),
    (("2026-02-10", "2026-02-10T08:00:00"), ("'report.instrument_calibrated_on': expected a "
                                            "date (YYYY-MM-DD)")),
    (('"A. Sandström"', '"  "'), "'report.operator': is empty; expected text"),
    (('name = "air temperature"\n', ""), "missing key 'report.sensors[1].name'"),
    (("[report]", "[raport]"), "unknown key 'raport'"),
    (("2026-01-15", "15"), "'report.sensors[1].calibrated_on': expected a date"),
])
def test_bad_meta_file_is_one_line_and_writes_nothing(ess_file, tmp_path, capsys, edit, words):
    meta = tmp_path / "meta.toml"
    assert edit[0] in META
    meta.write_text(META.replace(*edit), encoding="utf-8")
    out = tmp_path / "report"
    assert main(["report", str(ess_file), "--out", str(out), "--meta", str(meta)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "meta.toml" in err[0], err
    assert not out.exists()


def test_meta_in_python_is_a_table_or_a_file(ess_file, tmp_path):
    import tomllib

    import backlash as bl

    table = tomllib.loads(META)
    result = bl.report(ess_file, meta=table)
    assert result.meta.operator == "A. Sandström" and result.meta.sensors[0].serial == \
        "XC80-T-998"
    files = result.write(tmp_path / "r")
    assert "XL80-123456" in _flat(pdf_pages(files["pdf"])[0])
    with pytest.raises(bl.InputError, match="report.instrument_serial"):
        bl.report(ess_file, meta={"report": {**table["report"], "instrument_serial": 5}})
