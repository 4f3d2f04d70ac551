"""The diagnosis of a circular test: the radial deviation of both runs as a least-squares sum
of error signatures, each effect with its standard uncertainty.

Geometry: on a circle of radius R the tool is nominally at
:math:`(R\\cos\\theta, R\\sin\\theta)` (first axis along 0 deg; CCW: :math:`\\theta` grows,
:math:`s = +1`; CW: :math:`s = -1`). An error :math:`(e_1, e_2)` of the two axes changes the
radius by its projection :math:`\\Delta r = e_1\\cos\\theta + e_2\\sin\\theta`. The signatures
per unit of each effect:

- play of axis 1 [um]: :math:`\\pm\\tfrac12 \\cos\\theta`, + after the axis passed its +
  extreme (0 deg), - after its - extreme (180 deg), in either direction (CCW:
  :math:`\\tfrac12 s\\,\\mathrm{sgn}(\\sin\\theta)\\cos\\theta`);
- play of axis 2 [um]: :math:`\\pm\\tfrac12 \\sin\\theta`, + after 90 deg, - after 270 deg;
- reversal spike of an axis [um]: :math:`\\sum_r \\sum_k c_k e^{-d_r/\\lambda_k}`, :math:`d_r`
  the travel since the axis's reversal :math:`\\theta_r` (axis 1 at 0 and 180 deg, axis 2 at
  90 and 270 deg); reported: the peak of the sum;
- out-of-squareness [um/m]: :math:`\\tfrac{R}{2000}\\sin 2\\theta` (:math:`e_1 = \\alpha y`:
  the second axis leans towards the first);
- scale mismatch [ppm]: :math:`\\tfrac{R}{2000}\\cos 2\\theta` (first axis minus second);
- servo mismatch [ms]: :math:`s\\,\\tfrac{F}{120}\\sin 2\\theta` (lag of the first axis minus
  the second: :math:`e_i = -v_i \\Delta t_i`);

with R in mm and F in mm/min. Play is lost motion: the axis trails its command by half the
play in the direction it moves, so its deviation steps by the play where it reverses (the
circle is tangent to the other axis there); the step is taken up while the motor travels the
play, :math:`R (1 - \\cos d) = b` (``_take_up``), so the fit is repeated with the plays it
found. A reversal spike is the axis sticking after it reverses, a short peak decaying over a
few degrees; its shape is not assumed: it is a sum of exponentials of decay lengths
``SPIKE_BASIS_DEG`` (0.75 to 12 deg), and its height is the peak of that sum over the first
``SPIKE_SPAN_DEG`` after the reversal. Each run also gets its own mean radius
and centre offset (ISO 230-4's least-squares centre: :math:`1, \\cos\\theta, \\sin\\theta`)
and its own drift: the bar's length changing steadily with the time of the run (a thermal
drift), linear in the travel since the run's first reading in the order of capture
(``features.circle.travel_deg``). Unfitted,
a drift of a few tenths of a um over a run leaks into the 2-per-revolution terms (its sawtooth
holds sin 2θ) and moved the squareness by 0.3 um/m, three times its uncertainty.
The 2-per-revolution terms of squareness and servo mismatch share :math:`\\sin 2\\theta`; they
separate because servo mismatch changes sign with the direction, so both runs are needed.

The standard uncertainty of each effect is a delete-one-block jackknife over the path
([Kunsch1989]; the cluster jackknife CR3 of [MacKinnon2017] with blocks as clusters): each
run is cut into sectors of ``SPIKE_SPAN_DEG`` (30 deg) from 0 deg, the fit is repeated
leaving out one sector at a time, and the spread of the refits is the covariance. Readings
of one sector share what the signatures do not hold (the shape of a spike, of a take-up, a
bar's wobble), so neighbouring readings are not independent evidence, and the signatures are
shared between the axes and the runs; a refit without a sector carries both into the spread,
which a residual covariance :math:`s^2 (A^T A)^{-1}` does not. With G sectors the standard
uncertainty is stated for k = 2: the jackknife's standard error times
:math:`t_{0.975, G-1}/2`, so that :math:`\\pm 2u` is the 95 % interval ([GUM] G.3, G.6.4).
Fewer than ``MIN_SECTORS`` sectors, or a signature that rests on one sector, give no
uncertainty (NaN) and a note.

References
----------
[Kunsch1989] Künsch H. R., The jackknife and the bootstrap for general stationary
observations, Annals of Statistics 17(3), 1989. [MacKinnon2017] MacKinnon J. G., Webb M. D.,
Wild bootstrap inference for wildly different cluster sizes, J. Applied Econometrics 32(2),
2017. [GUM] JCGM 100:2008, annex G. ISO 230-4:2022, Circular tests for numerically controlled machine tools, annex on the
interpretation of the path. Kakino Y., Ihara Y., Shinohara A., Accuracy inspection of NC
machine tools by double ball bar method, Hanser, 1993.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from features.circle import travel_deg

# The effects reported; "_1"/"_2": the plane's first/second axis.
TERMS = ("backlash_1", "backlash_2", "spike_1", "spike_2", "squareness", "scale", "servo")
# The linear columns before the spikes', in this order.
LINEAR = ("backlash_1", "backlash_2", "squareness", "scale", "servo")
# Decay lengths [deg] of the exponentials whose sum is a reversal spike of any short shape.
SPIKE_BASIS_DEG = (0.75, 1.5, 3.0, 6.0, 12.0)
# Reversal angles [deg] of the plane's first and second axis.
REVERSALS_DEG = ((0.0, 180.0), (90.0, 270.0))
# Travel after a reversal [deg] over which a spike's peak is looked for.
SPIKE_SPAN_DEG = 30.0
# A play is reported negative when it lies below 0 by more than this many standard
# uncertainties (an over-compensated axis, or CW and CCW swapped).
NEGATIVE_K = 2.0
# CW and CCW read as swapped when the fit with the labels exchanged leaves residuals this many
# times smaller (root mean square): the steps and spikes then follow the reversals.
SWAPPED_RMS_RATIO = 1.5
# Fewer jackknife sectors (over both runs) than this give no uncertainty: t(0.975) of fewer
# than 7 degrees of freedom exceeds 2.4 and the spread of so few refits is itself uncertain
# by a third or more.
MIN_SECTORS = 8
# Columns of each run's own: mean radius, centre (cos, sin), drift over a revolution.
OWN = 4


@dataclass(frozen=True)
class Diagnosis:
    """The effects of a circular test, fitted.

    Attributes
    ----------
    value, u : dict of str to float
        By ``TERMS``: play [um], reversal spike height [um], out-of-squareness [um/m], scale
        mismatch [ppm], servo mismatch [ms], and their standard uncertainties (NaN where the
        runs do not hold the effect, e.g. an arc without that axis's reversal).
    rms_residual_um : float
        Root mean square of what the signatures leave unexplained [um].
    notes : tuple of str
        Why the uncertainties are missing, when they are.
    """

    value: dict
    u: dict
    rms_residual_um: float
    notes: tuple = ()


def _travel_since(theta_deg: np.ndarray, s: float, reversal_deg: float) -> np.ndarray:
    """Travel [deg] since the path last passed ``reversal_deg`` (direction ``s``), in (0, 360]:
    a reading taken at the reversal itself is the last one before it (the axis has arrived at
    its extreme, not yet left it)."""
    d = np.mod(s * (theta_deg - reversal_deg), 360.0)
    return np.where(d < 1e-9, 360.0, d)


def _step(theta_deg: np.ndarray, s: float, reversals) -> np.ndarray:
    """The error of an axis with a play of 1 [um], along the axis: +1/2 after it passed its +
    extreme (its first reversal, 0 or 90 deg: it now moves in - and trails on the + side),
    -1/2 after its - extreme, in either direction of the circle."""
    first, second = (_travel_since(theta_deg, s, r) for r in reversals)
    return np.where(first < second, 0.5, -0.5)


def _take_up(theta_deg: np.ndarray, s: float, reversals, radius_mm: float,
             play_um: float) -> np.ndarray:
    """The play's step as it happens: after a reversal the load waits until the motor has
    travelled the play, :math:`R (1 - \\cos d) = b`; in between the error moves from its old
    value (-1) to its new one (+1) as :math:`2 \\min(R (1 - \\cos d), b) / b - 1`."""
    if not play_um > 0:
        return np.ones_like(theta_deg)
    d = np.min([_travel_since(theta_deg, s, r) for r in reversals], axis=0)
    travel_um = radius_mm * 1000.0 * (1.0 - np.cos(np.radians(np.minimum(d, 90.0))))
    return 2.0 * np.minimum(travel_um, play_um) / play_um - 1.0


def spike_basis(travel_deg: np.ndarray) -> np.ndarray:
    """:math:`e^{-d/\\lambda_k}` for each ``SPIKE_BASIS_DEG``, one column each."""
    return np.column_stack([np.exp(-travel_deg / lam) for lam in SPIKE_BASIS_DEG])


def signatures(theta_deg: np.ndarray, direction: str, radius_mm: float, feed_mm_min: float,
               play_um=(0.0, 0.0)) -> np.ndarray:
    """The signature columns of one run [um per unit of each effect]: ``LINEAR``, then the
    spike basis of the first axis, then of the second.

    Parameters
    ----------
    theta_deg : ndarray
        Angles of the readings from the plane's first axis [deg].
    direction : {'CW', 'CCW'}
    radius_mm : float
        Nominal radius R [mm].
    feed_mm_min : float
        Feed F [mm/min].
    play_um : pair of float
        The plays [um] that shape each step as it is taken up (``_take_up``); 0: a sharp step.
    """
    s = 1.0 if direction == "CCW" else -1.0
    t = np.radians(theta_deg)
    c, n = np.cos(t), np.sin(t)
    steps = [_step(theta_deg, s, REVERSALS_DEG[k]) * _take_up(theta_deg, s, REVERSALS_DEG[k],
                                                                radius_mm, play_um[k])
             for k in (0, 1)]
    spikes = [sum(spike_basis(_travel_since(theta_deg, s, r)) for r in REVERSALS_DEG[k])
              for k in (0, 1)]
    return np.column_stack([
        steps[0] * c,
        steps[1] * n,
        radius_mm / 2000.0 * np.sin(2 * t),
        radius_mm / 2000.0 * np.cos(2 * t),
        s * feed_mm_min / 120.0 * np.sin(2 * t),
        *spikes[0].T, *spikes[1].T,
    ])


def _design(runs, radius_mm: float, feed_mm_min: float, play_um) -> np.ndarray:
    """Signature columns of every run, then each run's own radius, centre and drift columns
    (``OWN`` each)."""
    blocks = []
    for k, run in enumerate(runs):
        direction, theta = run[0], run[1]
        t = np.radians(theta)
        travel = run[3] if len(run) > 3 and run[3] is not None else travel_deg(direction, theta)
        own = np.zeros((len(theta), OWN * len(runs)))
        own[:, OWN * k:OWN * k + OWN] = np.column_stack(
            [np.ones_like(t), np.cos(t), np.sin(t), np.asarray(travel, float) / 360.0])
        blocks.append(np.hstack([signatures(theta, direction, radius_mm, feed_mm_min, play_um),
                                 own]))
    return np.vstack(blocks)


def _least_squares(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solve :math:`\\min \\lVert a c - y\\rVert` by the normal equations of the columns scaled
    to unit norm: a few dozen columns, well apart, and far faster than an SVD."""
    scale = np.linalg.norm(a, axis=0)
    b = a / scale
    try:
        return np.linalg.solve(b.T @ b, b.T @ y) / scale
    except np.linalg.LinAlgError:  # effects the runs cannot tell apart: the least-norm answer
        return np.linalg.lstsq(b, y, rcond=None)[0] / scale


def _fit(runs, y: np.ndarray, radius_mm: float, feed_mm_min: float, rounds: int = 4):
    """Least squares; the plays' take-up (a fraction of a degree) depends on the plays
    themselves, so the fit is repeated with the last plays until they settle. Returns the
    coefficients and covariance over every column (NaN where a column has no support), the
    residuals and why the covariance is missing (None when it is not)."""
    play = (0.0, 0.0)
    for _ in range(rounds):
        design = _design(runs, radius_mm, feed_mm_min, play)
        # A column without support (an arc missing an axis's reversal) is left out.
        norms = np.linalg.norm(design, axis=0)
        used = norms > 1e-9 * norms.max()
        coef = _least_squares(design[:, used], y)
        full = np.zeros(used.size)
        full[used] = coef
        play = (max(full[0], 0.0), max(full[1], 0.0))
    a = design[:, used]
    residual = y - a @ coef
    cov_used, why = _block_jackknife(a, y, _sectors(runs))
    cov = np.full((used.size, used.size), np.nan)
    cov[np.ix_(used, used)] = cov_used
    full[~used] = np.nan
    return full, cov, residual, why


def _sectors(runs) -> np.ndarray:
    """The jackknife's block of each reading: its run and its sector of ``SPIKE_SPAN_DEG``
    from 0 deg (reversals at 0, 90, 180, 270 deg fall on the sectors' edges, so a sector
    holds the spike span after at most one reversal)."""
    per_run = int(np.ceil(360.0 / SPIKE_SPAN_DEG))
    return np.concatenate([k * per_run + np.floor(np.mod(run[1], 360.0) / SPIKE_SPAN_DEG)
                           for k, run in enumerate(runs)]).astype(int)


def _block_jackknife(a: np.ndarray, y: np.ndarray, block: np.ndarray):
    """Covariance of the least-squares coefficients of ``a c = y`` by the delete-one-block
    jackknife, stated for k = 2 (module docstring): (G - 1)/G times the sum of the squared
    deviations of the G refits from their mean, times (t(0.975, G - 1)/2)². Returns
    (covariance, None), or (NaN covariance, why) when the blocks cannot give one."""
    from scipy.stats import t as student

    p = a.shape[1]
    labels = np.unique(block)
    g = len(labels)
    nan = np.full((p, p), np.nan)
    if g < MIN_SECTORS:
        return nan, (f"the runs hold {g} sectors of {SPIKE_SPAN_DEG:g} deg, fewer than the "
                     f"{MIN_SECTORS} the jackknife needs: no uncertainty")
    scale = np.linalg.norm(a, axis=0)
    b = a / scale
    xtx, xty = b.T @ b, b.T @ y
    refits = np.empty((g, p))
    for i, label in enumerate(labels):
        rows = block == label
        part = b[rows]
        reduced = xtx - part.T @ part
        # a signature that rests on this one sector is not estimable without it
        if np.linalg.cond(reduced) > 1e12:
            return nan, (f"a signature rests on the readings of one {SPIKE_SPAN_DEG:g} deg "
                         "sector alone: no uncertainty")
        refits[i] = np.linalg.solve(reduced, xty - part.T @ y[rows])
    refits /= scale
    spread = refits - refits.mean(axis=0)
    factor = (float(student.ppf(0.975, g - 1)) / 2.0) ** 2
    return (g - 1) / g * (spread.T @ spread) * factor, None


def _spike_peak(coef: np.ndarray, cov: np.ndarray, travel: np.ndarray) -> tuple[float, float]:
    """The largest excursion of a fitted spike at the travels [deg] where it was read (within
    ``SPIKE_SPAN_DEG`` after a reversal: between the reversal and the first reading after it
    the sum of exponentials is an extrapolation) [um], and its standard uncertainty (the
    covariance along the basis at that travel)."""
    travel = travel[travel <= SPIKE_SPAN_DEG]
    if np.isnan(coef).any() or travel.size == 0:
        return float("nan"), float("nan")
    basis = spike_basis(travel)
    shape = basis @ coef
    g = basis[int(np.argmax(np.abs(shape)))]
    return float(shape[np.argmax(np.abs(shape))]), float(np.sqrt(g @ cov @ g))


def diagnose(runs, radius_mm: float, feed_mm_min: float) -> Diagnosis:
    """Fit the error signatures to the runs of one circular test.

    Parameters
    ----------
    runs : list of (direction, theta_deg, deviation_um[, travel_deg])
        Each run's direction ('CW' or 'CCW'), angles [deg] and radial deviations [um], and the
        travel of each reading since the run's first ([deg], ``travel_deg``; without it the
        readings are taken in the order of capture). Both directions are needed to separate
        squareness from servo mismatch.
    radius_mm : float
        Nominal radius R [mm].
    feed_mm_min : float
        Feed F [mm/min].

    Returns
    -------
    Diagnosis
    """
    y = np.concatenate([run[2] for run in runs])
    coef, cov, residual, why = _fit(runs, y, radius_mm, feed_mm_min)
    value = {name: float(coef[i]) for i, name in enumerate(LINEAR)}
    u = {name: float(np.sqrt(cov[i, i])) for i, name in enumerate(LINEAR)}
    k = len(SPIKE_BASIS_DEG)
    for axis, first in ((0, len(LINEAR)), (1, len(LINEAR) + k)):
        part = slice(first, first + k)
        travel = np.concatenate([_travel_since(theta, 1.0 if direction == "CCW" else -1.0, r)
                                 for direction, theta, *_ in runs for r in REVERSALS_DEG[axis]])
        value[f"spike_{axis + 1}"], u[f"spike_{axis + 1}"] = _spike_peak(
            coef[part], cov[part, part], travel)
    return Diagnosis({t: value[t] for t in TERMS}, {t: u[t] for t in TERMS},
                     float(np.sqrt(np.mean(residual ** 2))), (why,) if why else ())


def negative_plays(diagnosis: Diagnosis, k: float = NEGATIVE_K) -> list[str]:
    """The play terms (``backlash_1``, ``backlash_2``) below 0 by more than ``k`` standard
    uncertainties."""
    return [t for t in ("backlash_1", "backlash_2")
            if diagnosis.value[t] + k * diagnosis.u[t] < 0]


def exchanged(runs) -> list:
    """The runs with CW and CCW exchanged (a travel given counts the other way round too)."""
    out = []
    for run in runs:
        other = ("CW" if run[0] == "CCW" else "CCW", *run[1:3])
        if len(run) > 3 and run[3] is not None:
            other += (np.mod(-np.asarray(run[3], float), 360.0),)
        out.append(other)
    return out


def swapped_fit(runs, radius_mm: float, feed_mm_min: float,
                diagnosis: Diagnosis) -> Diagnosis | None:
    """The diagnosis of ``runs`` with CW and CCW exchanged, when it explains them clearly
    better than ``diagnosis`` (their own fit): its residuals ``SWAPPED_RMS_RATIO`` times
    smaller. A swapped pair reads as negative plays, the steps taken up and the spikes placed
    before the reversals; an over-compensated axis also reads as a negative play, but the
    exchanged fit does not explain it better. None otherwise."""
    other = diagnose(exchanged(runs), radius_mm, feed_mm_min)
    if other.rms_residual_um * SWAPPED_RMS_RATIO <= diagnosis.rms_residual_um:
        return other
    return None
