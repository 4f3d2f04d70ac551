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
from pipeline.reports.iso_chart import DOWN, UP, draw_readings
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
        assert "instrument: not recorded in the readings" in page
        for key in ("A", "E", "M", "R", "B", "B_mean"):
            assert f"{want[key]:.3f}" in page and f"{want[key]:.3f}" in html, key
        for row in want["per_target"]:
            for key in ("mean_up", "mean_down", "s_up", "s_down", "B_i", "R_i"):
                assert f"{row[key]:.3f}" in page, (path.name, row["target"], key)
    # the ESS page: figures ± U (hand values of tests/test_iso_uncertainty.py), outliers ringed
    assert "B         43.459 ± 4.115" in pages[0] and "outlier (ISO" in pages[0]
    assert "93.2" in pages[0] and "62.8" in pages[0] and "93.2" not in pages[1]
    assert html.count("<h2>") == 2 and html.count("data:image/png;base64,") == 2
    assert "Standard: <b>ISO 230-2:2014</b>" in html


def test_the_chart_rings_exactly_the_flagged_readings(ess_file):
    readings = read_readings(ess_file)
    _, ax = new_figure(4, 3, nrows=1, ncols=1)
    draw_readings(ax, readings, iso230.outliers(readings))
    (ring,) = [line for line in ax.lines if line.get_label() == "outlier (ISO flag)"]
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
    # the two readings ISO flags on the ESS file, none on the PSI file
    assert rings == [[62.8, 93.2], []]
