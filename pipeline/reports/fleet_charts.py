"""Small inline SVG charts for the fleet site: a sparkline per axis for the fleet table and
the charts of an axis page (history with forecast band and the last recorded forecast, ISO
230-2 chart, wear-rate map, compensation history).

The fleet site draws up to a few dozen charts per run; matplotlib costs about a quarter of a
second per figure (``pipeline.reports.report_page.new_figure`` and ``savefig``), which alone would
exceed the command's time budget on a fleet of twelve axes, so these charts are written as SVG
text directly: a few hundred bytes each, vector, embedded in the page (nothing to fetch, no
script). The markup carries no ``xmlns`` (an inline ``<svg>`` in HTML does not need one), so a
page holds no URL at all.

Every chart is a ``Plot``: data ranges mapped onto a pixel box, layers added in drawing order
(bands, lines, points with error bars, reference lines), axes with ticks, a legend. A chart
over time counts days from an axis's first visit (``days_since``: the analysis's UTC times
mapped onto the chart's axis); the charts draw what they are given and compute nothing else.
"""

from __future__ import annotations

import datetime as dt
import html
import math

import numpy as np

# matplotlib's default colours, so the site reads like the product's other reports
BLUE, ORANGE, GREEN, RED, GREY = "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#7f7f7f"
PURPLE = "#9467bd"
FONT = "font-family='system-ui, sans-serif'"
CHAR_PX = 6.6  # mean width of a character of the 11 px labels [px], for the legend layout


def days_since(origin, times) -> np.ndarray:
    """The chart's x of each of ``times`` (datetimes): days [d] since ``origin``."""
    return np.array([(t - origin).total_seconds() for t in times], float) / 86400.0


def unit_label(unit: str) -> str:
    """How a page writes a unit: µm for ``um``, the rest as it is (``arcsec``)."""
    return "µm" if unit == "um" else unit


def _num(value: float) -> str:
    return f"{value:.1f}"


def _points(xs, ys) -> str:
    return " ".join(f"{_num(x)},{_num(y)}" for x, y in zip(xs, ys))


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """Round tick values covering [lo, hi], about ``n`` of them (steps 1, 2, 2.5, 5 x 10^k)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(n, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(v, 10) for v in np.arange(first, hi + step * 1e-9, step)]


def tick_text(value: float) -> str:
    return f"{value:g}" if abs(value) >= 1e-9 else "0"


def date_ticks(lo: dt.date, hi: dt.date, n: int = 6) -> list[dt.date]:
    """First days of months between ``lo`` and ``hi``, every 1, 2, 3, 6, 12 or 24 months so
    that at most about ``n`` remain."""
    months = (hi.year - lo.year) * 12 + hi.month - lo.month + 1
    step = next((s for s in (1, 2, 3, 6, 12, 24, 60) if months / s <= n), 120)
    ticks, year, month = [], lo.year, lo.month
    while (year, month) <= (hi.year, hi.month):
        day = dt.date(year, month, 1)
        if lo <= day <= hi and (year * 12 + month - 1) % step == 0:
            ticks.append(day)
        year, month = (year + 1, 1) if month == 12 else (year, month + 1)
    return ticks


class Plot:
    """A chart of ``width`` x ``height`` pixels over data ranges ``x`` and ``y`` (each a
    (low, high) pair); ``margins`` (left, right, top, bottom) [px] hold ticks and labels."""

    def __init__(self, width: int, height: int, x: tuple, y: tuple,
                 margins: tuple = (52, 12, 22, 34)):
        self.width, self.height = width, height
        self.left, self.right, self.top, self.bottom = margins
        (x0, x1), (y0, y1) = x, y
        x1 = float(x1) if x1 > x0 else float(x0) + 1.0
        xpad = 0.02 * (x1 - x0)
        self.x0, self.x1 = float(x0) - xpad, x1 + xpad
        pad = 0.06 * (y1 - y0) if y1 > y0 else max(abs(y0) * 0.1, 0.5)
        self.y0, self.y1 = float(y0) - pad, float(y1) + pad
        self.layers: list[str] = []

    # ---- mapping -----------------------------------------------------------------------
    def px(self, x):
        span = self.width - self.left - self.right
        return self.left + (np.asarray(x, float) - self.x0) / (self.x1 - self.x0) * span

    def py(self, y):
        span = self.height - self.top - self.bottom
        return self.top + (self.y1 - np.asarray(y, float)) / (self.y1 - self.y0) * span

    # ---- layers ------------------------------------------------------------------------
    def band(self, xs, lo, hi, colour: str, opacity: float = 0.2) -> None:
        """A filled band between ``lo`` and ``hi`` over ``xs``."""
        xs, lo, hi = (np.asarray(v, float) for v in (xs, lo, hi))
        keep = np.isfinite(lo) & np.isfinite(hi)
        if keep.sum() < 2:
            return
        xs, lo, hi = xs[keep], lo[keep], hi[keep]
        outline = _points(self.px(xs), self.py(hi)) + " " + _points(self.px(xs[::-1]),
                                                                     self.py(lo[::-1]))
        self.layers.append(f"<polygon points='{outline}' fill='{colour}' "
                           f"fill-opacity='{opacity}' stroke='none'/>")

    def line(self, xs, ys, colour: str, width: float = 1.5, dash: str = "") -> None:
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        keep = np.isfinite(xs) & np.isfinite(ys)
        if keep.sum() < 2:
            return
        style = f" stroke-dasharray='{dash}'" if dash else ""
        self.layers.append(f"<polyline points='{_points(self.px(xs[keep]), self.py(ys[keep]))}' "
                           f"fill='none' stroke='{colour}' stroke-width='{width}'{style}/>")

    def dots(self, xs, ys, colour: str, radius: float = 3.0, err=None) -> None:
        """Points, with vertical error bars ± ``err`` when given."""
        ys = np.asarray(ys, float)
        px, py = self.px(xs), self.py(ys)
        parts = []
        if err is not None:
            e = np.broadcast_to(np.asarray(err, float), ys.shape)
            parts += [f"<line x1='{_num(x)}' x2='{_num(x)}' y1='{_num(a)}' y2='{_num(b)}' "
                      f"stroke='{colour}' stroke-width='1'/>"
                      for x, a, b in zip(px, self.py(ys - e), self.py(ys + e))
                      if math.isfinite(a) and math.isfinite(b)]
        parts += [f"<circle cx='{_num(x)}' cy='{_num(y)}' r='{radius}' fill='{colour}'/>"
                  for x, y in zip(px, py) if math.isfinite(y)]
        self.layers.append("".join(parts))

    def marks(self, xs, ys, colour: str, shape: str, size: float = 3.5, err=None) -> None:
        """Points drawn as open ``square`` or ``diamond`` markers, with vertical error bars
        ± ``err`` when given: evidence of another kind than the filled dots beside them."""
        ys = np.asarray(ys, float)
        parts = []
        if err is not None:
            e = np.broadcast_to(np.asarray(err, float), ys.shape)
            parts += [f"<line x1='{_num(x)}' x2='{_num(x)}' y1='{_num(lo)}' y2='{_num(hi)}' "
                      f"stroke='{colour}' stroke-width='1'/>"
                      for x, lo, hi in zip(self.px(xs), self.py(ys - e), self.py(ys + e))
                      if math.isfinite(lo) and math.isfinite(hi)]
        parts += [_marker(shape, colour, x, y, size)
                  for x, y in zip(self.px(xs), self.py(ys)) if math.isfinite(y)]
        self.layers.append("".join(parts))

    def vline(self, x: float, colour: str = GREY, dash: str = "4 3") -> None:
        px = _num(float(self.px(x)))
        self.layers.append(f"<line x1='{px}' x2='{px}' y1='{self.top}' "
                           f"y2='{self.height - self.bottom}' stroke='{colour}' "
                           f"stroke-width='1' stroke-dasharray='{dash}'/>")

    def hline(self, y: float, colour: str = RED, dash: str = "") -> None:
        py = _num(float(self.py(y)))
        style = f" stroke-dasharray='{dash}'" if dash else ""
        self.layers.append(f"<line x1='{self.left}' x2='{self.width - self.right}' y1='{py}' "
                           f"y2='{py}' stroke='{colour}' stroke-width='1'{style}/>")

    def vspan(self, x0: float, x1: float, colour: str = RED, opacity: float = 0.12) -> None:
        a, b = sorted((float(self.px(x0)), float(self.px(x1))))
        self.layers.append(f"<rect x='{_num(a)}' y='{self.top}' width='{_num(max(b - a, 1.0))}' "
                           f"height='{self.height - self.top - self.bottom}' fill='{colour}' "
                           f"fill-opacity='{opacity}'/>")

    # ---- frame -------------------------------------------------------------------------
    def axes(self, x_ticks: list[tuple[float, str]], y_label: str, x_label: str = "") -> None:
        """Frame, grid, tick labels: ``x_ticks`` as (value, text); y ticks are chosen here."""
        right, base = self.width - self.right, self.height - self.bottom
        frame = (f"<rect x='{self.left}' y='{self.top}' width='{right - self.left}' "
                 f"height='{base - self.top}' fill='none' stroke='#99a'/>")
        parts = [frame]
        for value in nice_ticks(self.y0, self.y1):
            y = _num(float(self.py(value)))
            parts.append(f"<line x1='{self.left}' x2='{right}' y1='{y}' y2='{y}' "
                         f"stroke='#e4e7eb'/><text x='{self.left - 5}' y='{y}' "
                         f"text-anchor='end' dominant-baseline='middle'>"
                         f"{tick_text(value)}</text>")
        for value, text in x_ticks:
            half = 3.4 * len(text)
            if not half <= float(self.px(value)) <= self.width - half:
                continue  # its label would be cut at the edge
            x = _num(float(self.px(value)))
            parts.append(f"<line x1='{x}' x2='{x}' y1='{base}' y2='{base + 4}' stroke='#99a'/>"
                         f"<text x='{x}' y='{base + 15}' text-anchor='middle'>"
                         f"{html.escape(text)}</text>")
        mid = (self.top + base) / 2
        parts.append(f"<text x='12' y='{_num(mid)}' text-anchor='middle' "
                     f"transform='rotate(-90 12 {_num(mid)})'>{html.escape(y_label)}</text>")
        if x_label:
            parts.append(f"<text x='{_num((self.left + right) / 2)}' y='{self.height - 3}' "
                         f"text-anchor='middle'>{html.escape(x_label)}</text>")
        self.layers.insert(0, "".join(parts))

    def legend(self, items: list[tuple[str, str, str]]) -> None:
        """Rows of (kind, colour, text) entries above the plot, wrapped at the chart's width;
        kind 'line', 'dot', 'band' or 'dash'. The top margin holds 14 px per row."""
        rows, x = [[]], float(self.left)
        for item in items:
            width = 26 + CHAR_PX * len(item[2])
            if rows[-1] and x + width > self.width - self.right:
                rows.append([])
                x = float(self.left)
            rows[-1].append((x, *item))
            x += width
        parts = []
        for i, row in enumerate(rows):
            y = self.top - 9 - 14 * (len(rows) - 1 - i)
            for x, kind, colour, text in row:
                parts.append(_legend_key(kind, colour, x, y)
                             + f"<text x='{_num(x + 16)}' y='{y}' dominant-baseline='middle'>"
                             f"{html.escape(text)}</text>")
        self.layers.append("".join(parts))

    def svg(self, label: str, css_class: str = "chart") -> str:
        """The chart as an inline ``<svg>`` element; ``label`` is its accessible name."""
        label = html.escape(label, quote=True)
        return (f"<svg class='{css_class}' width='{self.width}' height='{self.height}' "
                f"viewBox='0 0 {self.width} {self.height}' role='img' aria-label='{label}' "
                f"{FONT} font-size='11'><title>{label}</title>{''.join(self.layers)}</svg>")


def _marker(shape: str, colour: str, x: float, y: float, size: float) -> str:
    """An open square or diamond of half-width ``size`` [px] centred on (x, y)."""
    if shape == "square":
        points = [(x - size, y - size), (x + size, y - size), (x + size, y + size),
                  (x - size, y + size)]
    else:
        r = size * 1.3
        points = [(x, y - r), (x + r, y), (x, y + r), (x - r, y)]
    return (f"<polygon points='{' '.join(f'{_num(a)},{_num(b)}' for a, b in points)}' "
            f"fill='white' stroke='{colour}' stroke-width='1.5'/>")


def _legend_key(kind: str, colour: str, x: float, y: float) -> str:
    if kind in ("square", "diamond"):
        return _marker(kind, colour, x + 6, y, 3.5)
    if kind == "dot":
        return f"<circle cx='{_num(x + 6)}' cy='{y}' r='3' fill='{colour}'/>"
    if kind == "band":
        return (f"<rect x='{_num(x)}' y='{y - 5}' width='12' height='10' fill='{colour}' "
                f"fill-opacity='0.25'/>")
    dash = " stroke-dasharray='4 3'" if kind == "dash" else ""
    return (f"<line x1='{_num(x)}' x2='{_num(x + 12)}' y1='{y}' y2='{y}' stroke='{colour}' "
            f"stroke-width='2'{dash}/>")


# --------------------------------------------------------------------------- the fleet's charts
def _span(*arrays) -> tuple[float, float]:
    values = np.concatenate([np.asarray(a, float).ravel() for a in arrays if a is not None])
    values = values[np.isfinite(values)]
    return (float(values.min()), float(values.max())) if len(values) else (0.0, 1.0)


def _recorded_span(recorded: dict | None) -> tuple[list, list]:
    """The day and the values of a recorded forecast, for the chart's ranges."""
    if recorded is None:
        return [], []
    values = [recorded[k] for k in ("fit", "low", "high") if recorded.get(k) is not None]
    return [recorded["day"]], values


def _draw_recorded(plot: Plot, recorded: dict | None, radius: float, width: float) -> None:
    """A recorded forecast: a purple point at its day with its 95 % interval as a bar."""
    if recorded is None:
        return
    if recorded.get("low") is not None:
        plot.line([recorded["day"]] * 2, [recorded["low"], recorded["high"]], PURPLE, width)
    plot.dots([recorded["day"]], [recorded["fit"]], PURPLE, radius)


def sparkline(history: dict, forecast: dict | None, *, threshold_um=None,
              alert: bool = False, label: str = "", recorded: dict | None = None) -> str:
    """A 150 x 36 px sparkline: the backlash per visit [um] over time, change points as
    ticks, the forecast band ahead, the last recorded forecast and the threshold as a faint
    line.

    ``history``: ``days`` (since the first visit), ``backlash_um``, ``change_days``;
    ``forecast``: ``days``, ``fit``, ``low``, ``high`` [um], or None; ``recorded``: ``day``,
    ``fit``, ``low``, ``high`` (bounds may be None), or None.
    """
    days, y = history["days"], history["backlash_um"]
    ahead = forecast or {"days": [], "low": [], "high": [], "fit": []}
    rec_days, rec_values = _recorded_span(recorded)
    x_hi = max([*days, *ahead["days"], *rec_days]) if len(days) else 1.0
    y_lo, y_hi = _span(y, ahead["low"], ahead["high"], rec_values)
    if threshold_um is not None and threshold_um <= 1.5 * y_hi:
        y_lo, y_hi = min(y_lo, threshold_um), max(y_hi, threshold_um)
    plot = Plot(150, 36, (0.0, x_hi), (y_lo, y_hi), margins=(3, 4, 3, 3))
    colour = RED if alert else BLUE
    if forecast:
        plot.band(ahead["days"], ahead["low"], ahead["high"], ORANGE, 0.3)
        plot.line(ahead["days"], ahead["fit"], ORANGE, 1.0, "3 2")
    if threshold_um is not None and y_lo <= threshold_um <= y_hi:
        plot.hline(threshold_um, RED, "2 2")
    for d in history.get("change_days", []):
        plot.vline(d, GREY, "2 2")
    plot.line(days, y, colour, 1.5)
    plot.dots(days[-1:], y[-1:], colour, 2.5)
    _draw_recorded(plot, recorded, 2.5, 2.0)
    return plot.svg(label or "backlash history", "spark")


def history_chart(history: dict, forecast: dict | None, trend: dict | None, origin: dt.date,
                  *, threshold_um=None, crossing: tuple = (None, None, None),
                  due_days: float | None = None, label: str = "",
                  recorded: dict | None = None, unit: str = "um",
                  evidence: list | None = None) -> str:
    """The axis's backlash per visit with ±2 sigma bars, the Theil-Sen trend since the last
    change point, change points (dashed), the forecast band, the threshold and the crossing
    interval (shaded) and the day the next visit is due (``due_days``, green). Days are
    counted from ``origin`` (the first visit's date); values and threshold are in ``unit``
    (``um``, ``arcsec`` for a rotary axis).

    ``trend``: ``days`` and ``fit`` of the trend line, or None; ``crossing``: (date, early,
    late) in days, each None when unknown; ``recorded``: the last recorded forecast (``day``,
    ``fit``, ``low``, ``high``), drawn in purple with its interval, or None; ``evidence``:
    the other sources' points as recorded, each a dict ``shape`` (``square``, ``diamond``),
    ``colour``, ``text`` (its legend entry), ``days``, ``values``, ``u`` (standard
    uncertainty), drawn as open markers with ±2u bars.
    """
    days, y, sigma = (np.asarray(history[k], float) for k in ("days", "backlash_um", "sigma_um"))
    evidence = [e for e in evidence or [] if len(e["days"])]
    for e in evidence:
        e["values"], e["u"] = np.asarray(e["values"], float), np.asarray(e["u"], float)
    ahead = forecast or {"days": [], "low": [], "high": [], "fit": []}
    rec_days, rec_values = _recorded_span(recorded)
    x_hi = max([*days, *ahead["days"], *rec_days, *([] if due_days is None else [due_days]),
                *(d for e in evidence for d in e["days"])])
    x_lo = min([0.0, *(d for e in evidence for d in e["days"])])
    y_lo, y_hi = _span(y - 2 * sigma, y + 2 * sigma, ahead["low"], ahead["high"], rec_values,
                       *(e["values"] + k * e["u"] for e in evidence for k in (-2, 2)))
    if threshold_um is not None:
        y_lo, y_hi = min(y_lo, threshold_um), max(y_hi, threshold_um)
    plot = Plot(760, 300, (x_lo, x_hi), (min(y_lo, 0.0) if y_lo < 0.5 else y_lo, y_hi),
                margins=(52, 14, 40, 34))
    items = [("dot", BLUE, "backlash per visit (±2σ)")]
    if crossing[1] is not None:
        plot.vspan(crossing[1], crossing[2] if crossing[2] is not None else x_hi)
        items.append(("band", RED, "crossing interval"))
    if forecast:
        plot.band(ahead["days"], ahead["low"], ahead["high"], ORANGE, 0.22)
        items.append(("band", ORANGE, "forecast: the next measurement (95 %)"))
    if trend:
        plot.line(trend["days"], trend["fit"], ORANGE, 1.8)
        items.append(("line", ORANGE, "Theil-Sen trend"))
    for d in history.get("change_days", []):
        plot.vline(d)
    if history.get("change_days"):
        items.append(("dash", GREY, "change point"))
    if threshold_um is not None:
        plot.hline(threshold_um)
        items.append(("line", RED, f"threshold {threshold_um:g} {unit_label(unit)}"))
    if due_days is not None:
        plot.vline(due_days, GREEN, "6 3")
        items.append(("dash", GREEN, "next visit due"))
    plot.line(days, y, BLUE, 1.0)
    plot.dots(days, y, BLUE, 3.5, err=2 * sigma)
    for e in evidence:
        plot.marks(e["days"], e["values"], e["colour"], e["shape"], err=2 * e["u"])
        items.append((e["shape"], e["colour"], e["text"]))
    if recorded is not None:
        _draw_recorded(plot, recorded, 4.5, 3.0)
        items.append(("dot", PURPLE, "last recorded forecast (95 %)"))
    ticks = date_ticks(origin + dt.timedelta(days=float(x_lo)),
                       origin + dt.timedelta(days=float(x_hi)))
    plot.axes([((d - origin).days, d.strftime("%Y-%m")) for d in ticks],
              f"backlash [{unit_label(unit)}]")
    plot.legend(items)
    return plot.svg(label or "backlash history and forecast")


def iso_chart(targets: dict, unit: str, position_unit: str, label: str = "") -> str:
    """ISO 230-2 chart of one test: mean deviation up and down against the target with their
    ±2s bands and the bidirectional mean (``targets``: ``target``, ``mean_up``, ``mean_down``,
    ``s_up``, ``s_down``, ``mean_bi`` arrays)."""
    t = np.asarray(targets["target"], float)
    up, down = np.asarray(targets["mean_up"], float), np.asarray(targets["mean_down"], float)
    s_up, s_down = np.asarray(targets["s_up"], float), np.asarray(targets["s_down"], float)
    y_lo, y_hi = _span(up - 2 * s_up, up + 2 * s_up, down - 2 * s_down, down + 2 * s_down)
    plot = Plot(760, 280, (float(t.min()), float(t.max())), (y_lo, y_hi))
    for mean, s, colour in ((up, s_up, BLUE), (down, s_down, RED)):
        plot.band(t, mean - 2 * s, mean + 2 * s, colour, 0.15)
        plot.line(t, mean, colour, 1.6)
        plot.dots(t, mean, colour, 2.5)
    plot.line(t, targets["mean_bi"], "#222222", 1.0, "4 3")
    plot.axes([(v, tick_text(v)) for v in nice_ticks(float(t.min()), float(t.max()), 7)],
              f"deviation [{unit}]", f"target [{position_unit}]")
    plot.legend([("line", BLUE, "mean + (up) ±2s"), ("line", RED, "mean − (down) ±2s"),
                 ("dash", "#222222", "bidirectional mean")])
    return plot.svg(label or "ISO 230-2 chart")


def wear_chart(rate_map: dict, label: str = "", unit: str = "um",
               position_unit: str = "mm") -> str:
    """The wear-rate map w(x) [``unit`` per 1000 h] along the axis [``position_unit``] with its
    interval (``rate_map``: ``position_mm``, ``rate``, ``low``, ``high`` arrays)."""
    x = np.asarray(rate_map["position_mm"], float)
    y_lo, y_hi = _span(rate_map["low"], rate_map["high"], rate_map["rate"], [0.0])
    plot = Plot(760, 240, (float(x.min()), float(x.max())), (y_lo, y_hi))
    plot.band(x, rate_map["low"], rate_map["high"], GREEN, 0.2)
    plot.line(x, rate_map["rate"], GREEN, 2.0)
    plot.hline(0.0, GREY)
    plot.axes([(v, tick_text(v)) for v in nice_ticks(float(x.min()), float(x.max()), 7)],
              f"wear rate [{unit_label(unit)}/1000 h]", f"position [{position_unit}]")
    plot.legend([("line", GREEN, "wear rate w(x)"), ("band", GREEN, "95 % interval")])
    return plot.svg(label or "wear-rate map")


def compensation_chart(records: list[dict], unit: str, position_unit: str,
                       label: str = "") -> str:
    """The compensation history of an axis: the correction table of every recorded
    compensation against the target (correction = -error, per approach direction), the
    latest in colour (+ blue, − red) over the earlier ones in grey (``records`` oldest first,
    each with ``table``: ``target``, ``error_up_um``, ``error_down_um``)."""
    tables = [r["table"] for r in records]
    x_lo, x_hi = _span(*[t["target"] for t in tables])
    y_lo, y_hi = _span(*[-np.asarray(t[k], float) for t in tables
                         for k in ("error_up_um", "error_down_um")], [0.0])
    plot = Plot(760, 260, (x_lo, x_hi), (y_lo, y_hi), margins=(52, 12, 36, 34))
    plot.hline(0.0, GREY)
    for t in tables[:-1]:
        for k in ("error_up_um", "error_down_um"):
            plot.line(t["target"], -np.asarray(t[k], float), "#b0b4bb", 1.0)
    latest = tables[-1]
    for k, colour in (("error_up_um", BLUE), ("error_down_um", RED)):
        plot.line(latest["target"], -np.asarray(latest[k], float), colour, 2.2)
        plot.dots(latest["target"], -np.asarray(latest[k], float), colour, 2.5)
    plot.axes([(v, tick_text(v)) for v in nice_ticks(x_lo, x_hi, 7)],
              f"correction [{unit}]", f"target [{position_unit}]")
    items = [("line", BLUE, f"latest, approach + ({records[-1]['recorded_at'][:10]})"),
             ("line", RED, "latest, approach −")]
    if len(tables) > 1:
        items.append(("line", "#b0b4bb", f"{len(tables) - 1} earlier"))
    plot.legend(items)
    return plot.svg(label or "compensation history")
