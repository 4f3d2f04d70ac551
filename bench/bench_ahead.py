"""Compensation ahead of wear: the ``fleet`` preset's axes (4 machines, uniform wear plus a worn
zone at 120 mm) used two shifts a day (16 h) with a maintenance visit every 90 days (1440 h).
A wear map trained on five visits writes the table frozen at the last visit (``--at-hours`` of
that visit) and the table forecast for the middle of the next interval (the default); the twin
is measured five times over that interval, and the backlash each table leaves (true lost motion
minus the table's backlash at the targets the table covers: the model's, interior ones for the
direct axis's paper target) is averaged over the interval (trapezoid in time):
its mean |.| over the targets and its largest value (the reversal error B of ISO 230-2 after
compensation, without the noise of a measurement)."""

from __future__ import annotations

import time
import warnings

import numpy as np

from bench import size

QUARTERS, TRAINED, MACHINES = size(4, 2), size(5, 3), size(4, 1)


def main() -> None:
    from features.readings.errors import BacklashWarning
    from models.physics.campaign import load_config, simulate
    from pipeline.workflows.compensate import compensate
    from pipeline.workflows.train import train

    config = load_config({"fleet": {"machines": MACHINES, "axes": ["X"], "adjust_at": [],
                                    "visits": QUARTERS * TRAINED + 1,
                                    "interval_days": 90 / QUARTERS, "hours_per_day": 16.0}},
                         preset="fleet")
    start = time.perf_counter()
    sim = simulate(config, seed=0)
    visits = sorted(sim.readings["visit"].astype(str).unique())
    seen = visits[:QUARTERS * (TRAINED - 1) + 1:QUARTERS]
    readings = sim.readings[sim.readings["visit"].astype(str).isin(seen)].copy()
    for column in readings.select_dtypes("category"):
        readings[column] = readings[column].cat.remove_unused_categories()
    with warnings.catch_warnings():
        # the campaign adjusts no axis (adjust_at = []), and training says so for each
        warnings.filterwarnings("ignore", "wear clock .*no mechanical adjustment found",
                                BacklashWarning)
        model = train(readings, model="wear-map").trained
        spacing = float(np.diff(sorted(sim.truth["target"].unique())).min())
        last = float(sim.visits.groupby("visit")["operating_hours"].first()[seen[-1]])
        frozen = compensate(model, at_hours=last, spacing=spacing).profiles
        middle = compensate(model, spacing=spacing).profiles
    elapsed = time.perf_counter() - start
    print(f"{MACHINES} axes, interval {last / (TRAINED - 1):g} h after the visit at {last:g} h; "
          f"mid-interval table at {middle[0].at_hours:g} h ({elapsed:.1f} s)")
    print("axis     mean |e| frozen  ahead  ratio    max |e| frozen  ahead  ratio  [um]")
    ratios = []
    for f, m in zip(frozen, middle, strict=True):
        fm, fx = _interval_error(sim, visits[QUARTERS * (TRAINED - 1):], f)
        mm, mx = _interval_error(sim, visits[QUARTERS * (TRAINED - 1):], m)
        ratios.append(mm / fm)
        print(f"{f.machine_id} {f.axis}   {fm:14.3f} {mm:6.3f} {mm / fm:6.2f}    "
              f"{fx:14.3f} {mx:6.3f} {mx / fx:6.2f}")
    print(f"time-averaged mean |error|, ahead / frozen: {np.mean(ratios):.2f} "
          f"(linear wear, exact table: 0.50)")


def _interval_error(sim, during: list[str], profile) -> tuple[float, float]:
    """Over the measurements ``during`` the interval (trapezoid in time): the mean over the
    targets the table covers and the largest |true lost motion - the table's backlash| [um]."""
    truth = sim.truth[sim.truth["machine_id"].astype(str) == profile.machine_id]
    means, peaks = [], []
    for visit in during:
        part = truth[truth["visit"].astype(str) == visit]
        true = part.groupby("target", observed=True)["true_backlash_um"].mean()
        true = true[(true.index >= profile.target.min()) & (true.index <= profile.target.max())]
        table = np.interp(true.index.to_numpy(float), profile.target, -profile.reversal)
        error = np.abs(true.to_numpy() - table)
        means.append(float(error.mean()))
        peaks.append(float(error.max()))
    weights = np.r_[0.5, np.ones(len(during) - 2), 0.5]
    return (float(weights @ means / weights.sum()), float(weights @ peaks / weights.sum()))


if __name__ == "__main__":
    main()
