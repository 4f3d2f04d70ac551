"""``backlash report``: the printable test report (PDF and HTML) of the real ecmc tests,
checked page by page against the hand calculation of the files."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import pytest

from features import iso230
from features.readings import read_readings
from pipeline.cli import main
from pipeline.iso_chart import draw_readings
from pipeline.report_page import new_figure
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
