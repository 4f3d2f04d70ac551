"""The one shell of every HTML report and the one way figures are made and saved.

Figures use matplotlib's object API (``matplotlib.figure.Figure``) and never pyplot, so no
global state, no backend switch and no figure left open; they are written atomically.
"""

from __future__ import annotations

import html
from pathlib import Path

from features.readings.fileio import atomic_path, write_text

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
.alert { background: #fff4f0; padding: 0.6em 1em; border-left: 4px solid #b8431f; }
"""


def page(title: str, body: str) -> str:
    """A complete HTML page: ``title`` (plain text, escaped here) and ``body`` (HTML)."""
    title = html.escape(title)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">\n'
            f"<title>{title}</title><style>{CSS}</style></head>\n"
            f"<body>\n<h1>{title}</h1>\n{body}\n</body></html>\n")


def write_page(path, title: str, body: str) -> Path:
    return write_text(path, page(title, body))


# Room [in] for tick labels, axis labels and a title around fixed-margin figures.
MARGINS_IN = {"left": 0.75, "right": 0.2, "bottom": 0.55, "top": 0.4}


def new_figure(width_in: float, height_in: float, *, fixed_margins: bool = False, **subplots):
    """A figure of the given size [in]; with ``subplots`` keywords (nrows, ncols, sharex...)
    returns ``(figure, axes)`` like ``plt.subplots``, else the figure alone.

    Axes are placed by matplotlib's constrained layout, which costs an extra drawing pass;
    ``fixed_margins`` places them with ``MARGINS_IN`` instead, for simple figures a command
    draws on every run."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=110,
                 layout=None if fixed_margins else "constrained")
    if fixed_margins:
        m = MARGINS_IN
        fig.subplots_adjust(left=m["left"] / width_in, right=1 - m["right"] / width_in,
                            bottom=m["bottom"] / height_in, top=1 - m["top"] / height_in,
                            wspace=0.15)
    if subplots:
        return fig, fig.subplots(**subplots)
    return fig


def save_figure(fig, path) -> Path:
    """Write ``fig`` as PNG, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
