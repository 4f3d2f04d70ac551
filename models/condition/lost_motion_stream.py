"""Lost motion on a stream: per reversal window, then per day from the windows' statistics.

The daily estimator of ``models.condition.lost_motion`` (docs/monitor.md) written as sufficient
statistics that add up, so that a day seen in one piece (``monitor`` on a file) and a day seen
sample by sample as a controller sends it (``watch``) give the same lost motion by
construction: both feed the samples' 40 ms bins to one ``AxisStream`` and read the day from
one combiner (``combine``). What a day keeps is bounded and does not grow with its samples:

- the motion state of the last bin (direction, travel since the last reversal, time since the
  last acceleration: what decides whether a bin is usable);
- per group of moves (a move is the motion between two reversals or gaps; move g belongs to
  group g mod ``GROUPS``) the normal equations of the fit restricted to that group's bins:
  the dense block (direction/2, velocity), the lead-error spline's banded block and their
  cross terms, and the right-hand sides. The day's normal equations are their sum;
- the reversals counted, the samples used.

Two choices make the fit decomposable where the batch fit of old was not:

- the lead-error spline lives on a fixed grid of absolute position (a control point every
  ``LEAD_SPACING_MM``), not on the day's range with a count that depends on the day's
  samples, so every bin lands in its columns as it arrives. The P-spline penalty ties a
  control point without samples to its neighbours, as before;
- the cluster-robust (sandwich) uncertainty takes the groups of moves as its clusters: a
  cluster's score a'X_g'(y_g - X_g beta) is linear in its normal equations, so it needs only
  the group's, and the moves of a group are independent as the moves are. With fewer moves
  than ``GROUPS`` each group is one move: the sandwich of old.

The gap threshold (ten median sampling periods) is taken from the day's first
``GAP_PROBE`` bins; a stream holds those bins until it has them (or the day ends), so the
threshold is the same whichever pieces the day came in.
"""

from __future__ import annotations

import numpy as np

# The bins (a whole number make a day): see ``models.condition.lost_motion.BIN_S``.
BIN_NS = 40_000_000
DAY_NS = 86_400_000_000_000
STEADY = 1e-3
SMOOTHING = 1e-6
MIN_REVERSALS = 2
SEPARABLE = 1e-3
# A control point of the lead-error spline every this much travel [mm or deg], on a grid
# anchored at 0: a screw pitch's wave of 10 mm or more is followed (four points a wave), as
# the old rule's 2.7 mm on 350 mm of travel did.
LEAD_SPACING_MM = 2.5
# At most this many control points (50 m of travel): positions spanning more are counts or
# a wrong unit, and the day's statistics would grow without bound (1.5 kB a control point).
MAX_COLUMNS = 20_000
# Moves are pooled into this many groups, the sandwich's clusters: with thousands of moves a
# day 31 degrees of freedom give the uncertainty within about 13 % of itself, and the day's
# state stays a few hundred kB whatever its length.
GROUPS = 32
# Fewer clusters (moves) than this give no uncertainty: the jackknife's spread of 4 or fewer
# refits has 3 or fewer degrees of freedom, where t(0.975) is 3.2 or more and the spread
# itself uncertain by half or more (Cameron & Miller 2015, section VI).
MIN_CLUSTERS = 5
# Bins at the start of a day from which the gap threshold is taken.
GAP_PROBE = 2001
# Per column of a group: C[j,j], C[j,j+1], C[j,j+2], B[j,0], B[j,1], S'y[j]
_WIDTH = 6
# Per group: A00, A01, A11, D'y 0, D'y 1, samples (weight)
_DENSE = 6


class DayStats:
    """The sufficient statistics of one machine axis's day (module docstring)."""

    def __init__(self, day: int):
        self.day = int(day)
        self.col0 = 0
        self.cols = np.zeros((GROUPS, 0, _WIDTH))
        self.dense = np.zeros((GROUPS, _DENSE))
        self.reversals = 0
        self.samples = 0.0

    def add(self, group, x, y, d0, d1, w) -> None:
        """Add usable bins: group, position x [mm], y = motor - load, d0 = direction/2,
        d1 = velocity, w = samples behind each bin."""
        if not len(x):
            return
        scaled = x / LEAD_SPACING_MM
        first = np.floor(scaled)
        u = scaled - first
        first = first.astype(np.int64)
        b = ((1.0 - u) ** 2 / 2.0, 0.5 + u - u * u, u * u / 2.0)
        self._cover(int(first.min()), int(first.max()) + 3)
        k = self.cols.shape[1]
        base = group * k + (first - self.col0)
        flat = self.cols.reshape(-1, _WIDTH)
        n = flat.shape[0]
        wy, wd0, wd1 = w * y, w * d0, w * d1
        for a in range(3):
            at = base + a
            ba = b[a]
            for slot, weights in ((0, w * ba * ba), (3, wd0 * ba), (4, wd1 * ba), (5, wy * ba)):
                flat[:, slot] += np.bincount(at, weights=weights, minlength=n)
            if a < 2:
                flat[:, 1] += np.bincount(at, weights=w * ba * b[a + 1], minlength=n)
        flat[:, 2] += np.bincount(base, weights=w * b[0] * b[2], minlength=n)
        for slot, weights in enumerate((wd0 * d0, wd0 * d1, wd1 * d1, wd0 * y, wd1 * y, w)):
            self.dense[:, slot] += np.bincount(group, weights=weights, minlength=GROUPS)
        self.samples += float(w.sum())

    def _cover(self, lo: int, hi: int) -> None:
        """Grow the column range to hold columns lo..hi-1."""
        k = self.cols.shape[1]
        span = max(hi, self.col0 + k) - min(lo, self.col0 if k else lo)
        if span > MAX_COLUMNS:
            from features.readings.errors import InputError

            raise InputError(f"positions span {span * LEAD_SPACING_MM:.6g} mm in one day, more "
                             f"than the {MAX_COLUMNS * LEAD_SPACING_MM:g} mm an axis travels: "
                             "positions in counts or a wrong unit; expected mm (deg)")
        if k == 0:
            self.col0, self.cols = lo, np.zeros((GROUPS, hi - lo, _WIDTH))
            return
        new0, new1 = min(self.col0, lo), max(self.col0 + k, hi)
        if (new0, new1) != (self.col0, self.col0 + k):
            grown = np.zeros((GROUPS, new1 - new0, _WIDTH))
            grown[:, self.col0 - new0:self.col0 - new0 + k] = self.cols
            self.col0, self.cols = new0, grown

    # ------------------------------------------------------------------ persistence
    def to_arrays(self, prefix: str) -> dict:
        return {f"{prefix}day": np.array([self.day, self.col0, self.reversals]),
                f"{prefix}samples": np.array([self.samples]),
                f"{prefix}cols": self.cols, f"{prefix}dense": self.dense}

    @classmethod
    def from_arrays(cls, arrays, prefix: str) -> DayStats:
        day, col0, reversals = (int(v) for v in arrays[f"{prefix}day"])
        out = cls(day)
        out.col0, out.reversals = col0, reversals
        out.samples = float(arrays[f"{prefix}samples"][0])
        out.cols = np.array(arrays[f"{prefix}cols"], float).reshape(GROUPS, -1, _WIDTH)
        out.dense = np.array(arrays[f"{prefix}dense"], float).reshape(GROUPS, _DENSE)
        return out


def combine(stats: DayStats) -> tuple:
    """The day's lost motion from its statistics: (lost_motion, u, reversals, samples, lag_s,
    control_points), lost motion and u in mm (deg); NaN when fewer than ``MIN_REVERSALS``
    reversals took up the play on both sides, or when direction and velocity are confounded
    (every move at one feed without rests)."""
    from scipy.linalg import solveh_banded

    samples = round(stats.samples)
    nan = (np.nan, np.nan, stats.reversals, samples, np.nan, 0)
    if stats.reversals < MIN_REVERSALS or stats.samples <= 0:
        return nan
    per_col = stats.cols.sum(axis=0)
    touched = np.flatnonzero(per_col[:, 0] > 0)
    lo, hi = int(touched[0]), int(touched[-1]) + 1
    groups = stats.cols[:, lo:hi]
    cols = per_col[lo:hi]
    k = hi - lo
    dense = stats.dense.sum(axis=0)
    n = dense[5]
    a_dense = np.array([[dense[0], dense[1]], [dense[1], dense[2]]])
    # 1 - r² of direction and velocity (uncentred); rests only leave no lag to fit, not a
    # confounded one
    r2 = dense[1] ** 2 / (dense[0] * dense[2]) if dense[0] > 0 and dense[2] > 0 else 0.0
    band = _penalty_band(k) * (SMOOTHING * n)
    band[2] += cols[:, 0]
    band[1, 1:] += cols[:-1, 1]
    band[0, 2:] += cols[:-2, 2]
    band[2] += 1e-12 * band[2].max()
    a_dense = a_dense + np.eye(2) * 1e-12 * max(a_dense[0, 0], a_dense[1, 1], 1e-300)
    cross = cols[:, 3:5]
    solved = solveh_banded(band, np.c_[cross, cols[:, 5]], check_finite=False)
    schur = a_dense - cross.T @ solved[:, :2]
    rhs = dense[3:5] - cross.T @ solved[:, 2]
    beta_d = np.linalg.solve(schur, rhs)
    if 1.0 - r2 < SEPARABLE:
        return (np.nan, np.nan, stats.reversals, samples, np.nan, k)
    u = _jackknife_u(stats, groups, band, a_dense, cross, cols, dense)
    return (float(beta_d[0]), u, stats.reversals, samples, float(beta_d[1]), k)


def _jackknife_u(stats: DayStats, groups, band, a_dense, cross, cols, dense) -> float:
    """The standard uncertainty of L stated for k = 2: the delete-one-cluster jackknife (CR3)
    over the groups of moves, times t(0.975, G - 1)/2 so that +-2u is the 95 % interval with
    the G - 1 degrees of freedom G clusters leave; NaN when the clusters cannot give one.

    Each refit leaves one group's normal equations out of the day's (the spline and the lag
    are refitted too, so what their fits take from the moves is in the spread). The plain
    cluster sandwich divides by G - 1 clusters' worth of scores that the fit has already
    shrunk; with the 6-10 moves of a working minute it was 1.5-2x too small (Bell &
    McCaffrey 2002; Cameron & Miller 2015), which the jackknife's refits are not
    (MacKinnon & Webb 2017)."""
    from scipy.linalg import LinAlgError, solveh_banded
    from scipy.stats import t as student

    used = np.flatnonzero(stats.dense[:, 5] > 0)
    g = len(used)
    if g < MIN_CLUSTERS:
        return np.nan
    out = np.empty(g)
    for i, j in enumerate(used):
        part, dense_g = groups[j], stats.dense[j]
        band_g = band.copy()
        band_g[2] -= part[:, 0]
        band_g[1, 1:] -= part[:-1, 1]
        band_g[0, 2:] -= part[:-2, 2]
        a_g = a_dense - np.array([[dense_g[0], dense_g[1]], [dense_g[1], dense_g[2]]])
        cross_g = cross - part[:, 3:5]
        try:
            solved = solveh_banded(band_g, np.c_[cross_g, cols[:, 5] - part[:, 5]],
                                   check_finite=False)
        except LinAlgError:
            return np.nan
        schur = a_g - cross_g.T @ solved[:, :2]
        # the day without this group must still tell the play from the lead error and the
        # lag: the direction keeps a share of its own variance (one direction left: none)
        if not schur[0, 0] > SEPARABLE * a_g[0, 0] or np.linalg.det(schur) <= 0:
            return np.nan
        rhs = dense[3:5] - dense_g[3:5] - cross_g.T @ solved[:, 2]
        out[i] = np.linalg.solve(schur, rhs)[0]
    spread = float(np.sqrt((g - 1) / g * np.sum((out - out.mean()) ** 2)))
    return spread * float(student.ppf(0.975, g - 1)) / 2.0


def _penalty_band(k: int) -> np.ndarray:
    """D'D of second differences D of k control points, in the upper banded form of
    ``scipy.linalg.solveh_banded`` (row 2 the diagonal, row 1 the first superdiagonal, row 0
    the second): each row of D is (1, -2, 1)."""
    band = np.zeros((3, k))
    if k > 2:
        band[2, :-2] += 1.0
        band[2, 1:-1] += 4.0
        band[2, 2:] += 1.0
        band[1, 1:-1] -= 2.0
        band[1, 2:] -= 2.0
        band[0, 2:] = 1.0
    return band


class AxisStream:
    """One machine axis's bins as they come, day by day (module docstring).

    ``feed`` takes bins in time order (their UTC day numbers, their times in seconds since
    that day's midnight, the channels' bin means and the samples behind each bin) and returns
    the days it closed: a bin of a later day closes the open day. ``close`` closes the open
    day (at stop, or at the end of a file). The state is plain arrays (``to_arrays``), so a
    watcher keeps it across restarts.
    """

    def __init__(self, take_up: float = 0.05, settle_s: float = 0.1):
        self.take_up, self.settle_s = float(take_up), float(settle_s)
        self.stats: DayStats | None = None
        self.pending: list[np.ndarray] = []  # bins held until the gap threshold is known
        self.threshold = np.nan
        # the motion state after the last bin processed (see ``_motion``)
        self.carry = None

    # ------------------------------------------------------------------ feeding
    def feed(self, day, t_s, commanded, motor, load, weight) -> list[tuple[int, tuple]]:
        """Add bins; the days closed by them, as (UTC day number, ``combine``'s tuple)."""
        day = np.asarray(day, np.int64)
        closed = []
        if not len(day):
            return closed
        cut = np.flatnonzero(day[1:] != day[:-1]) + 1
        columns = [np.asarray(v, float) for v in (t_s, commanded, motor, load, weight)]
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(day)]):
            d = int(day[a])
            if self.stats is not None and d != self.stats.day:
                if d < self.stats.day:
                    raise ValueError(f"day {d} after day {self.stats.day}: bins go back")
                closed.append(self._close())
            if self.stats is None:
                self.stats, self.carry, self.threshold = DayStats(d), None, np.nan
                self.pending = []
            self._add(np.stack([c[a:b] for c in columns]))
        return closed

    def close(self) -> list[tuple[int, tuple]]:
        """Close the open day, if any."""
        return [self._close()] if self.stats is not None else []

    def open_day(self) -> int | None:
        return None if self.stats is None else self.stats.day

    def _close(self) -> tuple[int, tuple]:
        if self.pending:
            self._settle_threshold()
        out = (self.stats.day, combine(self.stats))
        self.stats, self.carry, self.pending = None, None, []
        return out

    def _add(self, bins: np.ndarray) -> None:
        if np.isnan(self.threshold):
            self.pending.append(bins)
            if sum(p.shape[1] for p in self.pending) >= GAP_PROBE:
                self._settle_threshold()
            return
        self._process(bins)

    def _settle_threshold(self) -> None:
        held = np.concatenate(self.pending, axis=1)
        self.pending = []
        t = held[0]
        dt = np.diff(t[:GAP_PROBE])
        # ten sampling periods (the median of the day's first ones) without a sample
        self.threshold = 10 * float(np.median(dt)) if len(dt) else np.inf
        self._process(held)

    # ------------------------------------------------------------------ the motion
    def _process(self, bins: np.ndarray) -> None:
        t, commanded, motor, load, weight = bins
        n = len(t)
        c = self.carry
        first = c is None
        if first:  # the day's first bin: as ``models.condition.lost_motion.motion_state`` starts
            c = {"t": t[0] - 1.0, "c": commanded[0], "v": None, "dir": 0.0, "travel": 0.0,
                 "unsteady_t": -np.inf, "move": 0, "has": False, "prev_has": False,
                 "rev": False, "counted": False}
        dt = np.empty(n)
        dt[0] = t[0] - c["t"]
        np.subtract(t[1:], t[:-1], out=dt[1:])
        step = np.empty(n)
        step[0] = commanded[0] - c["c"]
        np.subtract(commanded[1:], commanded[:-1], out=step[1:])
        moving = np.abs(step) > 1e-9 * np.maximum(np.abs(commanded), 1.0)
        sign = np.where(moving, np.sign(step), 0.0)
        last = np.maximum.accumulate(np.where(moving, np.arange(n), -1))
        direction = np.where(last >= 0, sign[np.maximum(last, 0)], c["dir"])
        before_dir = np.r_[c["dir"], direction[:-1]]
        reversal = (direction != before_dir) & (before_dir != 0)
        gap = dt > self.threshold
        new_move = reversal | gap
        move = c["move"] + np.cumsum(new_move)
        acc = np.cumsum(np.abs(step))
        start = np.maximum.accumulate(np.where(new_move, np.arange(n), -1))
        travel = np.where(start >= 0, acc - acc[np.maximum(start, 0)], c["travel"] + acc)
        taken_up = (travel >= self.take_up) & (direction != 0)
        # a step within float rounding is a rest: bin means of a resting set point differ in
        # their last bits with the order they were summed in (a file at once, or a stream)
        velocity = np.divide(step, dt, out=np.zeros(n), where=(dt > 0) & moving)
        before = np.r_[velocity[0] if first else c["v"], velocity[:-1]]
        unsteady = (np.abs(velocity - before) > STEADY * np.maximum(np.abs(velocity),
                                                                     np.abs(before))) | gap
        if first:
            unsteady[0] = True
        since = t - np.maximum.accumulate(np.where(unsteady, t, c["unsteady_t"]))
        usable = taken_up & (since >= self.settle_s)
        # reversals with usable bins on both sides: counted when the later move gets its
        # first usable bin (the move before is over by then)
        local = move - c["move"]
        moves = int(local[-1]) + 1
        has = np.bincount(local, weights=usable, minlength=moves) > 0
        has[0] |= c["has"]
        prev_has = np.r_[c["prev_has"], has[:-1]]
        started = np.zeros(moves, bool)
        started[0] = c["rev"]  # the move carried over (its bins, if any, come first)
        started[local[new_move]] = reversal[new_move]
        count = started & has & prev_has
        count[0] &= not c["counted"]
        self.stats.reversals += int(count.sum())
        ended_counted = bool(started[-1] & has[-1] & prev_has[-1])
        if usable.any():
            y = motor - load
            self.stats.add(move[usable] % GROUPS, motor[usable], y[usable],
                           direction[usable] / 2.0, velocity[usable], weight[usable])
        self.carry = {"t": float(t[-1]), "c": float(commanded[-1]), "v": float(velocity[-1]),
                      "dir": float(direction[-1]), "travel": float(travel[-1]),
                      "unsteady_t": float(np.max(np.where(unsteady, t, c["unsteady_t"]))),
                      "move": int(move[-1]), "has": bool(has[-1]),
                      "prev_has": bool(prev_has[-1]), "rev": bool(started[-1]),
                      "counted": ended_counted}

    # ------------------------------------------------------------------ persistence
    _CARRY = ("t", "c", "v", "dir", "travel", "unsteady_t", "move", "has", "prev_has", "rev",
              "counted")

    def to_arrays(self, prefix: str = "") -> dict:
        """The state as named arrays (``numpy.savez``: nothing that runs code when loaded)."""
        out = {f"{prefix}options": np.array([self.take_up, self.settle_s, self.threshold])}
        if self.stats is None:
            return out
        out.update(self.stats.to_arrays(prefix))
        if self.carry is not None:
            out[f"{prefix}carry"] = np.array([float(self.carry[k]) for k in self._CARRY])
        if self.pending:
            out[f"{prefix}pending"] = np.concatenate(self.pending, axis=1)
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "") -> AxisStream:
        take_up, settle_s, threshold = (float(v) for v in arrays[f"{prefix}options"])
        out = cls(take_up, settle_s)
        out.threshold = threshold
        if f"{prefix}day" in arrays:
            out.stats = DayStats.from_arrays(arrays, prefix)
        if f"{prefix}carry" in arrays:
            values = [float(v) for v in arrays[f"{prefix}carry"]]
            carry = dict(zip(cls._CARRY, values))
            carry["move"] = int(carry["move"])
            for key in ("has", "prev_has", "rev", "counted"):
                carry[key] = bool(carry[key])
            out.carry = carry
        if f"{prefix}pending" in arrays:
            out.pending = [np.array(arrays[f"{prefix}pending"], float)]
        return out


class Binner:
    """Raw samples into the estimator's bins of ``BIN_NS`` on the UTC clock, as they come.

    ``add`` takes samples in time order (int64 ns since the epoch, the three channels) and
    returns the bins it completed, as ``AxisStream.feed``'s arguments; ``flush`` the last,
    open bin. Its open bin is plain numbers (``to_arrays``)."""

    def __init__(self):
        self.key = None  # the open bin's number and its sums: ns offsets, channels, count
        self.sums = np.zeros(5)

    def add(self, ns, commanded, motor, load):
        ns = np.asarray(ns, np.int64)
        if not len(ns):
            return _no_bins()
        key = ns // BIN_NS
        off = (ns - key * BIN_NS).astype(float)
        values = np.stack([off, np.asarray(commanded, float), np.asarray(motor, float),
                           np.asarray(load, float), np.ones(len(ns))])
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        keys = key[starts]
        sums = np.add.reduceat(values, starts, axis=1)
        if self.key is not None:
            if keys[0] == self.key:
                sums[:, 0] += self.sums
            else:
                keys = np.r_[self.key, keys]
                sums = np.c_[self.sums, sums]
        self.key, self.sums = int(keys[-1]), sums[:, -1].copy()
        return _bins(keys[:-1], sums[:, :-1])

    def flush(self):
        if self.key is None:
            return _no_bins()
        out = _bins(np.array([self.key]), self.sums[:, None])
        self.key, self.sums = None, np.zeros(5)
        return out

    def to_arrays(self, prefix: str = "") -> dict:
        if self.key is None:
            return {}
        return {f"{prefix}bin_key": np.array([self.key]), f"{prefix}bin_sums": self.sums}

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "") -> Binner:
        out = cls()
        if f"{prefix}bin_key" in arrays:
            out.key = int(arrays[f"{prefix}bin_key"][0])
            out.sums = np.array(arrays[f"{prefix}bin_sums"], float)
        return out


def _no_bins():
    empty = np.zeros(0)
    return np.zeros(0, np.int64), empty, empty, empty, empty, empty


def _bins(keys: np.ndarray, sums: np.ndarray):
    """(day, t_s since the day's midnight, commanded, motor, load, weight) of whole bins."""
    count = sums[4]
    start = keys * BIN_NS
    day = start // DAY_NS
    t_s = ((start - day * DAY_NS) + sums[0] / count) * 1e-9
    return day, t_s, sums[1] / count, sums[2] / count, sums[3] / count, count


def stream_days(ns, commanded, motor, load, *, take_up: float = 0.05,
                settle_s: float = 0.1) -> list[tuple[int, tuple]]:
    """Every day of one machine axis's samples (int64 ns, time order) through one
    ``AxisStream``, as ``monitor`` sees a file: the same bins and the same combiner as
    ``watch``."""
    binner, stream = Binner(), AxisStream(take_up, settle_s)
    days = stream.feed(*binner.add(ns, commanded, motor, load))
    days += stream.feed(*binner.flush())
    return days + stream.close()
