"""Volumetric compensation replicated: the seed paper's traditional and Abbe-aware models on
the machine twin, judged on the four body diagonals.

>>> import backlash as bl
>>> result = bl.volumetric(seed=0)                                   # doctest: +SKIP
>>> result.diagonals["PPP"]                                          # doctest: +SKIP
{'before_um': 44.0..., 'traditional_um': -4.4..., 'abbe_um': 1.6...}

The twin (``models.physics.machine.paper_machine``) is the paper's XHK714 with its travels and
errors sized on its Figure 5; six-channel laser tests off the tool point identify the 21
errors (``models.volumetric``) twice, once taking the optics to be at the tool point
(traditional) and once at their true offset (Abbe-aware); the control compensates with each,
and the four ISO 230-6 body diagonals are measured before and after [Chen2022]_.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path

from pipeline.results import Result
from pipeline.steps.parameters import SEED, Param
from pipeline.workflows import check_params
from pipeline.workflows.constraints import Interval

# The seed paper's Table 1 [um]: the extreme deviation before and after compensation
PAPER_TABLE1 = {
    "diagonals": {"NPP": {"before_um": -62.5, "traditional_um": -17.4,
                          "before_abbe_um": -65.5, "abbe_um": 9.4},
                  "NPN": {"before_um": -66.7, "traditional_um": -18.7,
                          "before_abbe_um": -78.3, "abbe_um": -6.6},
                  "PPP": {"before_um": -77.2, "traditional_um": -7.7,
                          "before_abbe_um": -76.5, "abbe_um": -4.2},
                  "PPN": {"before_um": -74.6, "traditional_um": -14.3,
                          "before_abbe_um": -79.7, "abbe_um": -7.1}},
    "axes": {"X": {"before_um": 65.6, "traditional_um": -15.3,
                   "before_abbe_um": -62.4, "abbe_um": -16.7},
             "Y": {"before_um": 24.1, "traditional_um": -12.8,
                   "before_abbe_um": 26.1, "abbe_um": -14.2},
             "Z": {"before_um": -77.2, "traditional_um": -19.2,
                   "before_abbe_um": -63.8, "abbe_um": -16.5}},
}
CIRCLE_PLANES = ("XY", "YZ", "ZX")


PARAMETERS = {
    "seed": Param(SEED, "random seed of the measurement noise"),
    "targets": Param((Interval(Integral, 5, 101, closed="both"),), "targets along each axis and "
                     "diagonal, 5 to 101 (default 11, as the paper)"),
    "radius_mm": Param((Interval(Real, 0, 500, closed="right"),), "radius of the circular "
                       "tests in circles.csv [mm]", metavar="MM"),
    "out": Param((str, os.PathLike, None), "folder for volumetric.json, diagonals.csv (every "
                 "reading) and circles.csv (ISO 230-4, SCHEMA section 11)", output="folder"),
}


@dataclass
class VolumetricResult(Result):
    """The paper's comparison replicated on the twin.

    Attributes
    ----------
    diagonals : dict
        Body diagonal (PPP, NPP, PPN, NPN) -> ``before_um``, ``traditional_um``, ``abbe_um``:
        the deviation of largest magnitude along it, with its sign [um].
    axes : dict
        Axis -> the same for its positioning at the tool point [um].
    identification : dict
        Model -> per axis and channel the largest |identified - true| error function over the
        travel [um, urad], and the squareness errors [urad].
    readings : DataFrame
        Every diagonal reading: ``diagonal``, ``stage``, ``target``, ``distance_mm``,
        ``deviation_um``.
    circles : DataFrame
        ISO 230-4 circles of the same twin in XY, YZ and ZX, CW and CCW (SCHEMA section 11).
    seed : int
    """

    diagonals: dict
    axes: dict
    identification: dict
    readings: object  # pandas.DataFrame
    circles: object  # pandas.DataFrame
    seed: int = 0
    parameters: dict = field(default_factory=dict)

    @property
    def finding(self) -> dict:
        """Per diagonal: does the Abbe-aware model leave less than the traditional one?"""
        return {name: abs(v["abbe_um"]) < abs(v["traditional_um"])
                for name, v in self.diagonals.items()}

    def write(self, out) -> dict[str, Path]:
        """``volumetric.json``, ``diagonals.csv`` (every reading) and ``circles.csv`` under
        ``out``."""
        from features.readings.fileio import atomic_path, write_json

        out = Path(out)
        self.files = {"json": write_json(out / "volumetric.json", self.to_json())}
        for role, frame in (("diagonals", self.readings), ("circles", self.circles)):
            path = out / f"{role}.csv"
            with atomic_path(path) as tmp:
                frame.to_csv(tmp, index=False)
            self.files[role] = path
        return self.files

    def to_json(self) -> dict:
        return {"seed": self.seed, "diagonals": self.diagonals, "axes": self.axes,
                "finding": {"abbe_below_traditional": self.finding,
                            "holds": all(self.finding.values())},
                "identification": self.identification, "paper": PAPER_TABLE1,
                "notes": list(self.notes)}


def volumetric(*, seed: int = 0, targets: int = 11, radius_mm: float = 150.0
               ) -> VolumetricResult:
    """Compensate the twin's volumetric error with the traditional and the Abbe-aware model.

    Parameters
    ----------
    seed : int
        Random seed of the measurement noise: the same seed gives the same numbers.
    targets : int
        Targets along each axis and each diagonal (the paper: 11).
    radius_mm : float
        Radius of the circular tests written beside [mm].

    Returns
    -------
    VolumetricResult
        The extreme body-diagonal and axis deviations before and after each compensation
        [um], how well each model identified the errors, every diagonal reading, and circles.

    References
    ----------
    .. [Chen2022] G. Chen et al. (seed 001), Table 1; ISO 230-6 (body diagonals).
    """
    check_params(PARAMETERS, {"seed": seed, "targets": targets, "radius_mm": radius_mm},
                 "volumetric")
    import pandas as pd

    from models import volumetric as vol
    from models.physics import machine as twin

    machine = twin.paper_machine()
    comparison = vol.compare(machine, vol.Setup(targets=targets), seed)
    circles = pd.concat([twin.circle_test(machine, plane=p, direction=d, radius_mm=radius_mm)
                         for p in CIRCLE_PLANES for d in ("CCW", "CW")], ignore_index=True)
    result = VolumetricResult(
        diagonals=comparison.extremes("diagonals"), axes=comparison.extremes("axes"),
        identification={n: vol.identification_error(g, machine.geometry)
                         for n, g in comparison.models.items()},
        readings=comparison.diagonals, circles=circles, seed=seed,
        parameters={"seed": seed, "targets": targets, "radius_mm": radius_mm})
    missed = [n for n, ok in result.finding.items() if not ok]
    if missed:
        result.notes.append(f"the Abbe-aware model did not leave less than the traditional one "
                            f"on {', '.join(missed)}")
    return result
