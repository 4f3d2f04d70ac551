"""Measurement uncertainty of an ISO 230-2 positioning test with a laser interferometer.

The contributors of ISO/TR 230-9 [ISO230-9] as the backlash paper lists them (section 5,
Table 3 [BacklashNN]): the laser (accuracy, wavelength stability, resolution), the
misalignment of the beam, the temperature (sensor, expansion coefficient, machine temperature
deviation from 20 °C), the environmental variation error from a drift test and the
repeatability of the setup (Abbe offset). They combine into u_P, the standard uncertainty of one
positional deviation at the measuring length, and into the expanded uncertainties (k = 2) of
the ISO 230-2 figures A, E, M, R, R↑/R↓ and B (Table 4).

Every function of the budget takes and returns plain numbers with the unit in its name or in
brackets in its docstring: lengths [mm], deviations [um], ppm of a length, temperatures [°C],
expansion coefficients [um/(mm·°C)]. A budget file is read by ``read_budget`` (``checked_budget``
also checks a budget built in code) into ``UncertaintyBudget``; ``evaluate`` turns it into the
budget's lines in one of two arithmetics:

- ``"iso"``: every length-dependent line at the measuring length L, the laser's accuracy and
  wavelength stability combined by root-sum-square (uncorrelated inputs, [GUM] 5.1.2);
- ``"paper"``: the lengths and the linear sum the paper's Table 3 lines use (the budget's
  ``[paper]`` table), which reproduces its printed numbers.

``per_test_um`` evaluates a budget at every test of a readings table (its own measuring length
and runs per direction): the expanded uncertainties the ``iso`` figures, the backlash targets
(``features.targets``) and the visit series (``features.visits``) carry.

References
----------
.. [ISO230-9] ISO/TR 230-9:2005, Test code for machine tools - Part 9: Estimation of
   measurement uncertainty for machine tool tests according to series ISO 230, basic equations.
.. [GUM] JCGM 100:2008, Evaluation of measurement data - Guide to the expression of uncertainty
   in measurement (BIPM; public).
.. [BacklashNN] Determination of backlash value in the feed motion system of machine tools
   using shallow neural networks, section 5, Tables 3 and 4 (see docs/references.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal, NamedTuple

from features.readings.errors import InputError

SQRT3 = math.sqrt(3.0)
REFERENCE_TEMPERATURE_C = 20.0  # ISO 1: the temperature lengths are stated at
KELVIN_AT_0_C = 273.15
ARITHMETICS = ("iso", "paper")
PARAMETERS = ("R_dir", "B", "R", "E", "M", "A")  # the figures of Table 4, in its order


# --------------------------------------------------------------------------- distributions
def rectangular_width(width):
    """Standard uncertainty of a rectangular distribution of full width ``width``.

    .. math:: u = \\frac{w}{2\\sqrt{3}}

    Parameters
    ----------
    width : float
        Full width of the interval the value lies in with equal probability [any unit].

    Returns
    -------
    float
        Standard uncertainty [the unit of ``width``].

    References
    ----------
    [GUM] 4.3.7 (half-width a: u = a/√3).
    """
    return width / (2.0 * SQRT3)


def rectangular_half_width(half_width):
    """Standard uncertainty of a rectangular distribution of half-width ``half_width``:
    u = a/√3 ([GUM] 4.3.7)."""
    return half_width / SQRT3


def root_sum_square(*u):
    """Combined standard uncertainty of uncorrelated contributors, √(Σ u_i²) [GUM 5.1.2]."""
    return math.sqrt(sum(x * x for x in u))


def linear_sum(*u):
    """Combined standard uncertainty of fully correlated contributors, Σ u_i [GUM 5.2.2,
    r = +1]: the upper bound of ``root_sum_square``."""
    return sum(u)


# --------------------------------------------------------------------------- the laser (u_D)
def ppm_of_length_um(ppm, length_mm):
    """A length-proportional error [um]: ``ppm`` parts per million of ``length_mm`` [mm].

    .. math:: e = a \\cdot L \\cdot 10^{-3}

    (1 ppm of 1 mm is 10⁻³ um.)
    """
    return ppm * length_mm * 1e-3


def laser_accuracy_um(accuracy_ppm, length_mm):
    """Standard uncertainty [um] of the laser's accuracy ±a [ppm] over ``length_mm`` [mm]:
    rectangular of half-width a·L, u = a·L/√3 ([GUM] 4.3.7; the manufacturer's figure taken
    as limits, as the paper does)."""
    return rectangular_half_width(ppm_of_length_um(accuracy_ppm, length_mm))


def wavelength_stability_um(stability_ppm, length_mm):
    """Standard uncertainty [um] of the laser wavelength's stability ±s [ppm] over
    ``length_mm`` [mm]: rectangular, u = s·L/√3 ([GUM] 4.3.7)."""
    return rectangular_half_width(ppm_of_length_um(stability_ppm, length_mm))


def resolution_uncertainty_um(resolution_um):
    """Standard uncertainty [um] of a reading of resolution r [um]: rectangular of full width
    r, u = r/(2√3) ([GUM] F.2.2.1)."""
    return rectangular_width(resolution_um)


# --------------------------------------------------------------------------- misalignment (u_M)
def misalignment_angle_deg(offset_mm, length_mm):
    """Angle γ [°] between the beam and the axis when the target drifts ``offset_mm`` [mm]
    off the beam over a travel of ``length_mm`` [mm]: sin γ = d/L."""
    return math.degrees(math.asin(min(offset_mm / length_mm, 1.0)))


def cosine_error_um(offset_mm, length_mm):
    """Cosine error ΔL_m [um] of a travel ``length_mm`` [mm] measured along a beam tilted by
    the angle of ``misalignment_angle_deg``: the beam sees L·cos γ.

    .. math:: \\Delta L_m = L (1 - \\cos\\gamma) \\approx \\frac{d^2}{2L}

    It always shortens the reading, so the error lies in [0, ΔL_m] (``rectangular_width``).
    """
    gamma = math.radians(misalignment_angle_deg(offset_mm, length_mm))
    return length_mm * 1e3 * (1.0 - math.cos(gamma))


# --------------------------------------------------------------------------- temperature (u_T)
def temperature_measurement_um(expansion_um_per_mm_c, length_mm, u_temperature_c):
    """Standard uncertainty [um] of the thermal correction from the uncertainty of the
    measured machine temperature: u_M = α·L·u(Θ) (linear expansion, sensitivity α·L).

    Parameters
    ----------
    expansion_um_per_mm_c : float
        Expansion coefficient α of the machine's scale [um/(mm·°C)] (steel: 0.012).
    length_mm : float
        Length the expansion acts over [mm].
    u_temperature_c : float
        Standard uncertainty of the temperature measurement u(Θ) [°C].
    """
    return expansion_um_per_mm_c * length_mm * u_temperature_c


def expansion_coefficient_um(delta_t_c, length_mm, u_expansion_um_per_mm_c):
    """Standard uncertainty [um] of the thermal correction from the uncertainty of the
    expansion coefficient: u_E = |ΔT|·L·u(α), with ΔT = T_M − 20 °C the machine's deviation
    from the reference temperature [°C] and u(α) [um/(mm·°C)]."""
    return abs(delta_t_c) * length_mm * u_expansion_um_per_mm_c


# --------------------------------------------------------------------------- setup (u_S)
def abbe_error_um(abbe_offset_mm, angular_deviation_um_per_m):
    """Setup error ΔL_S [um] from the Abbe offset O [mm] and the angular deviation gradient
    D [um/m] in both planes (pitch and yaw), as the paper's Table 3 computes it:

    .. math:: \\Delta L_S = \\sqrt{2} \\cdot O \\cdot D

    The product O·D (an angle times the offset) is the Abbe error [Chen2022]; the √2 (two
    planes added in quadrature) is read from the paper's numbers and not confirmed publicly.
    """
    return math.sqrt(2.0) * abbe_offset_mm * 1e-3 * angular_deviation_um_per_m


# --------------------------------------------------------------------------- Table 4
def mean_uncertainty_um(u_d, u_m, u_t, u_s, u_eve, n):
    """Standard uncertainty [um] of a mean positional deviation over ``n`` readings.

    .. math:: u(\\bar x)^2 = u_D^2 + u_M^2 + u_T^2 + u_S^2 + \\frac{u_{EVE}^2}{n}

    The laser, misalignment, temperature and setup errors repeat in every run; the
    environmental variation averages over the n runs. Reconstructed from the paper's U(E)
    (n = 5) and U(M) (n = 10); not confirmed from public material.
    """
    return math.sqrt(u_d ** 2 + u_m ** 2 + u_t ** 2 + u_s ** 2 + u_eve ** 2 / n)


def expanded_parameters_um(u_d, u_m, u_t, u_eve, u_s, cycles, k=2.0) -> dict:
    """Expanded uncertainties [um] of the ISO 230-2 figures (the paper's Table 4).

    .. math::

        U(R\\uparrow) = U(R\\downarrow) = k \\cdot 2u_{EVE}

        U(B) = k \\sqrt{(2u_S)^2 + (2u_{EVE})^2 / n}

        U(R) = k \\sqrt{(2u_S)^2 + (2u_{EVE})^2 / n + (2u_{EVE})^2}

        U(E) = U(E\\uparrow) = U(E\\downarrow) = k \\, u(\\bar x)_n

        U(M) = k \\, u(\\bar x)_{2n}

        U(A) = k \\sqrt{u_D^2 + u_M^2 + u_T^2 + u_S^2 + (8 + 3/n) u_{EVE}^2}

    B is a difference of the two directions' means at one target, so the length-proportional
    errors (laser, misalignment, temperature) cancel; the Abbe error changes sign with the
    direction (2u_S). R adds the repeatability to B as R↑ does (U(R)² = U(B)² + U(R↑)²).
    M averages both directions (2n readings). These forms are reconstructed: the paper prints
    only the results; they are the simplest combinations of its Table 3 contributors found to
    reproduce every printed value, and none is confirmed from public material.

    Parameters
    ----------
    u_d, u_m, u_t, u_eve, u_s : float
        Standard uncertainties [um] of the laser, misalignment, temperature, environmental
        variation and setup.
    cycles : int
        n, the runs per direction of the test (ISO 230-2: 5).
    k : float, default 2.0
        Coverage factor (k = 2: about 95 %, [GUM] 6.2).

    Returns
    -------
    dict
        ``R_dir`` (R↑ and R↓), ``B``, ``R``, ``E`` (E↑, E↓, E), ``M``, ``A`` [um].
    """
    u_r_dir = 2.0 * u_eve
    u_b = math.hypot(*reversal_terms_um(u_s, u_eve, cycles))
    return {
        "R_dir": k * u_r_dir,
        "B": k * u_b,
        "R": k * math.hypot(u_b, u_r_dir),
        "E": k * mean_uncertainty_um(u_d, u_m, u_t, u_s, u_eve, cycles),
        "M": k * mean_uncertainty_um(u_d, u_m, u_t, u_s, u_eve, 2 * cycles),
        "A": k * math.sqrt(u_d ** 2 + u_m ** 2 + u_t ** 2 + u_s ** 2
                           + (8.0 + 3.0 / cycles) * u_eve ** 2),
    }


def reversal_terms_um(u_s, u_eve, cycles) -> tuple[float, float]:
    """The two parts of the standard uncertainty of a reversal value B_i (Table 4's U(B)/k).

    .. math::

        u_{setup} = 2u_S, \\qquad u_{env} = \\frac{2u_{EVE}}{\\sqrt{n}}, \\qquad
        u(B) = \\sqrt{u_{setup}^2 + u_{env}^2}

    The Abbe error of the setup changes sign with the direction (2u_S) and repeats in every
    run of one setup: systematic. The environmental variation is a new draw in every run and
    averages over the n runs per direction. The laser, misalignment and temperature errors are
    proportional to the position and cancel in the difference of the two directions at one
    target. Reconstructed from the paper's Table 4 (``expanded_parameters_um``).

    Parameters
    ----------
    u_s, u_eve : float
        Standard uncertainties [um] of the setup (Abbe) and of the environmental variation.
    cycles : int
        n, the runs per direction.

    Returns
    -------
    (u_setup, u_env) : tuple of float
        Standard uncertainties [um].
    """
    return 2.0 * u_s, 2.0 * u_eve / math.sqrt(cycles)


# --------------------------------------------------------------------------- the budget file
@dataclass
class Device:
    """``[device]``: the laser's specification."""

    laser_accuracy_ppm: float
    wavelength_stability_ppm: float
    resolution_um: float


@dataclass
class Misalignment:
    """``[misalignment]``: how far the target drifts off the beam over the travel [mm]."""

    offset_mm: float


@dataclass
class Temperature:
    """``[temperature]``: sensor, machine temperature and expansion coefficient.

    ``sensor_width_c`` and ``expansion_width_um_per_mm_c`` are full widths of rectangular
    distributions (the paper's 0.7 °C and Δα = 0.002 give its u(Θ) = 0.2021 °C and
    u(α) = 0.0006). ``device_measurement_um`` and ``device_expansion_um`` are the laser's own
    standard uncertainties (zero for a laser that compensates air and material itself).
    """

    sensor_width_c: float
    machine_temperature_c: float
    expansion_um_per_mm_c: float
    expansion_width_um_per_mm_c: float
    device_measurement_um: float
    device_expansion_um: float


@dataclass
class Environment:
    """``[environment]``: E_VE, the range of a drift test at a fixed target [um]."""

    drift_um: float


@dataclass
class Setup:
    """``[setup]``: Abbe offset [mm] and the angular deviation gradient [um/m]."""

    abbe_offset_mm: float
    angular_deviation_um_per_m: float


@dataclass
class PaperArithmetic:
    """``[paper]``: where a published budget's lines depart from the measuring length and the
    root-sum-square (the backlash paper: laser lines at 100 mm, misalignment and temperature at
    200 mm, accuracy and wavelength stability added linearly)."""

    device_length_mm: float
    misalignment_length_mm: float
    thermal_length_mm: float
    device_sum: Literal["linear", "rss"] = "linear"


# Bounds of a budget's numbers. No length, contributor or factor in these units comes near
# 1e9 (1e9 um is a kilometre), and below it every square and sum of the lines stays finite:
# a budget beyond it is a typing slip, whose lines would overflow or print as inf.
MAX_VALUE = 1e9
MAX_CYCLES = 1_000_000


@dataclass
class UncertaintyBudget:
    """An ISO/TR 230-9 uncertainty budget of one axis, as read from a TOML file.

    Every key names its unit (``_mm``, ``_um``, ``_ppm``, ``_c`` for °C, ``_um_per_m``,
    ``_um_per_mm_c``); ``cycles`` is n, the runs per direction.
    """

    length_mm: float
    cycles: int
    device: Device
    misalignment: Misalignment
    temperature: Temperature
    environment: Environment
    setup: Setup
    axis: str = ""
    coverage_factor: float = 2.0
    arithmetic: Literal["iso", "paper"] = "iso"
    paper: PaperArithmetic | None = None
    name: str = ""  # how a report names the budget (default: its file's name)

    def digest(self) -> str:
        """The first 12 hex digits of the SHA-256 of the budget's values (its keys sorted, as
        JSON): two budgets with the same digest give the same uncertainties, whatever their
        files' comments or layout; a report prints it beside the budget's name."""
        import dataclasses
        import hashlib
        import json

        values = {k: v for k, v in dataclasses.asdict(self).items() if k != "name"}
        text = json.dumps(values, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]

    def check(self, file=None) -> None:
        """Refuse a non-physical budget: one ``InputError`` naming the key."""
        positive = {"length_mm": self.length_mm, "coverage_factor": self.coverage_factor}
        if self.paper is not None:
            positive.update({f"paper.{k}": v for k, v in vars(self.paper).items()
                             if k.endswith("_mm")})
        for key, value in positive.items():
            if not value > 0:
                raise InputError(f"must be > 0; got {value}", file=file, column=key)
        bounded = dict(positive)
        if self.cycles < 2:
            raise InputError(f"must be at least 2 runs per direction; got {self.cycles}",
                             file=file, column="cycles")
        if self.cycles > MAX_CYCLES:
            raise InputError(f"must be at most {MAX_CYCLES} runs per direction", file=file,
                             column="cycles")
        for section in ("device", "misalignment", "temperature", "environment", "setup"):
            for key, value in vars(getattr(self, section)).items():
                if key != "machine_temperature_c" and value < 0:
                    raise InputError(f"a contributor cannot be negative; got {value}",
                                     file=file, column=f"{section}.{key}")
                bounded[f"{section}.{key}"] = value
        for key, value in bounded.items():
            if abs(value) > MAX_VALUE:
                raise InputError(f"must be at most {MAX_VALUE:g} in its unit; got {value:g}",
                                 file=file, column=key)
        self._check_axis(file)
        self._check_temperature(file)
        if self.misalignment.offset_mm > min(self.lengths("iso")[1], self.lengths()[1]):
            raise InputError("the offset cannot exceed the length it drifts over",
                             file=file, column="misalignment.offset_mm")
        if self.arithmetic == "paper" and self.paper is None:
            raise InputError("arithmetic 'paper' needs a [paper] table (the lengths its lines "
                             "use)", file=file, column="arithmetic")

    def _check_axis(self, file) -> None:
        """``axis``, when given, names a linear axis: a budget's contributors are lengths."""
        from features.readings import schema

        if not self.axis:
            return
        if schema.is_rotary(self.axis):
            raise InputError(f"{self.axis!r} is a rotary axis: a budget's contributors are "
                             "lengths (mm, um), not angles; give the budget of a linear axis "
                             f"({', '.join(schema.LINEAR_AXES)})", file=file, column="axis")
        if self.axis.upper() not in schema.LINEAR_AXES:
            raise InputError(f"{self.axis!r} is not an axis; expected one of "
                             f"{', '.join(schema.LINEAR_AXES)} (a linear axis)", file=file,
                             column="axis")

    def _check_temperature(self, file) -> None:
        """``machine_temperature_c`` in the readings' plausible range of a machine temperature
        in °C; a value that is one in kelvin is named as such."""
        from features.readings.validation import PLAUSIBLE

        low, high, _ = PLAUSIBLE["machine_temp_c"]
        value = self.temperature.machine_temperature_c
        if low <= value <= high:
            return
        celsius = value - KELVIN_AT_0_C
        why = (f"a temperature in kelvin ({value:g} K = {celsius:.2f} °C), not in °C as the "
               "key's _c says" if low <= celsius <= high else "not a machine temperature in °C")
        raise InputError(f"{value:g} is {why}; expected °C between {low:g} and {high:g}",
                         file=file, column="temperature.machine_temperature_c")

    def lengths(self, arithmetic: str | None = None) -> tuple[float, float, float]:
        """The lengths [mm] of the laser, misalignment and thermal lines."""
        if (arithmetic or self.arithmetic) == "paper" and self.paper is not None:
            p = self.paper
            return p.device_length_mm, p.misalignment_length_mm, p.thermal_length_mm
        return self.length_mm, self.length_mm, self.length_mm


# Units a key may end with, longest first: a key with a known name and another unit is refused.
UNITS = ("_um_per_mm_c", "_um_per_m", "_ppm", "_um", "_mm", "_nm", "_m", "_c", "_k", "_deg")


def read_budget(source, file=None) -> UncertaintyBudget:
    """An ``UncertaintyBudget`` from a TOML file or a dict of the same shape.

    Raises
    ------
    InputError
        A missing or negative contributor, a key with the wrong unit (``laser_accuracy_um``
        for ``laser_accuracy_ppm``), a value carrying its own unit (``"0.5 ppm"``), an unknown
        key: one line naming the file and the key.
    """
    from collections.abc import Mapping

    from features.readings.config import from_table
    from features.readings.fileio import read_toml

    if isinstance(source, UncertaintyBudget):
        return source
    if isinstance(source, Mapping):
        table = source
    else:
        table, file = read_toml(source, "uncertainty budget"), str(source)
    _check_units(table, UncertaintyBudget, file)
    return from_table(table, UncertaintyBudget, file=file)


def checked_budget(source) -> UncertaintyBudget:
    """The budget of a TOML path, a dict or an ``UncertaintyBudget`` built in code, checked
    (``UncertaintyBudget.check``) in every case: a file or a dict is checked as it is read.

    Raises
    ------
    InputError
        As ``read_budget``, or a non-physical budget object (naming the key).
    """
    budget = read_budget(source)
    if source is budget:
        budget.check()
    return budget


def _check_units(table, cls, file, prefix: str = "") -> None:
    """Refuse units in the wrong place before the typed reading (whose messages are generic)."""
    import dataclasses
    import typing

    if not isinstance(table, dict):
        return
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    stems = {_split_unit(name): name for name in fields if _split_unit(name)[1]}
    for key, value in table.items():
        where = prefix + str(key)
        if key in fields:
            kind = hints[key]
            inner = [a for a in typing.get_args(kind) if dataclasses.is_dataclass(a)]
            if dataclasses.is_dataclass(kind) or inner:
                _check_units(value, kind if dataclasses.is_dataclass(kind) else inner[0],
                             file, where + ".")
            elif isinstance(value, str) and kind in (float, int) and any(
                    c.isalpha() for c in value):
                unit = _split_unit(key)[1].lstrip("_").replace("_", " ") or "its unit"
                raise InputError(f"expected a number in {unit}, got {value!r}: the unit "
                                 "belongs in the key's name, not in the value",
                                 file=file, column=where)
            continue
        stem, unit = _split_unit(str(key))
        known = [name for (s, u), name in stems.items() if s == stem and u != unit]
        if unit and known:
            raise InputError(f"wrong unit: {stem!r} is given in {_split_unit(known[0])[1][1:]}"
                             f", as {prefix + known[0]!r}", file=file, column=where)


def _split_unit(name: str) -> tuple[str, str]:
    for unit in UNITS:
        if name.endswith(unit) and len(name) > len(unit):
            return name[: -len(unit)], unit
    return name, ""


# --------------------------------------------------------------------------- evaluation
class Line(NamedTuple):
    """One line of a budget: a value with its formula, distribution and where it comes from."""

    key: str
    symbol: str
    value: float
    unit: str
    formula: str
    distribution: str
    source: str


def evaluate(budget: UncertaintyBudget, arithmetic: str | None = None) -> list[Line]:
    """The budget's lines in Table 3's order, in ``arithmetic`` ("iso" or "paper"; default the
    budget's own), ending with u_P, the standard uncertainty of one positional deviation.

    .. math:: u_P = \\sqrt{u_D^2 + u_M^2 + u_T^2 + u_{EVE}^2 + u_S^2}
    """
    arithmetic = arithmetic or budget.arithmetic
    if arithmetic == "paper" and budget.paper is None:
        raise InputError("arithmetic 'paper' needs the budget's [paper] table",
                         parameter="arithmetic")
    l_d, l_m, l_t = budget.lengths(arithmetic)
    linear = arithmetic == "paper" and budget.paper.device_sum == "linear"
    dev, mis, tem = budget.device, budget.misalignment, budget.temperature
    gum, here = "GUM 4.3.7", "paper Table 3"
    rect, none = "rectangular", "-"
    lines = [Line("L", "L", budget.length_mm, "mm", "measuring length", none, "input")]
    if arithmetic == "paper":
        lines += [Line("L_D", "L_D", l_d, "mm", "length of the laser lines", none, here),
                  Line("L_Mis", "L_Mis", l_m, "mm", "length of the misalignment lines", none,
                       here),
                  Line("L_T", "L_T", l_t, "mm", "length of the thermal lines", none, here)]
    u_acc = laser_accuracy_um(dev.laser_accuracy_ppm, l_d)
    u_wav = wavelength_stability_um(dev.wavelength_stability_ppm, l_d)
    u_est = (linear_sum if linear else root_sum_square)(u_acc, u_wav)
    u_res = resolution_uncertainty_um(dev.resolution_um)
    u_d = root_sum_square(u_est, u_res)
    lines += [
        Line("a", "a", dev.laser_accuracy_ppm, "ppm", "laser accuracy", none, "input"),
        Line("u_accuracy", "u_accuracy", u_acc, "um", "a·L_D/√3", rect, gum),
        Line("wavelength", "λ stability", dev.wavelength_stability_ppm, "ppm",
             "wavelength stability", none, "input"),
        Line("u_wavelength", "u_wavelength", u_wav, "um", "s·L_D/√3", rect, gum),
        Line("u_device_estimate", "u_device.estimate", u_est, "um",
             "u_accuracy + u_wavelength" if linear else "√(u_accuracy² + u_wavelength²)",
             "combined", "GUM 5.2.2 (r = 1), " + here if linear else "GUM 5.1.2"),
        Line("r", "r", dev.resolution_um, "um", "resolution", none, "input"),
        Line("u_resolution", "u_resolution", u_res, "um", "r/(2√3)", rect, "GUM F.2.2.1"),
        Line("u_D", "u_D", u_d, "um", "√(u_device.estimate² + u_resolution²)", "combined",
             "GUM 5.1.2"),
    ]
    d_lm = cosine_error_um(mis.offset_mm, l_m)
    u_m = rectangular_width(d_lm)
    lines += [
        Line("d", "misalignment", mis.offset_mm, "mm", "offset over the travel", none, "input"),
        Line("gamma", "γ", misalignment_angle_deg(mis.offset_mm, l_m), "deg",
             "asin(d/L_Mis)", none, "geometry"),
        Line("delta_L_m", "ΔL_m", d_lm, "um", "L_Mis·(1 − cos γ)", none, "geometry"),
        Line("u_M", "u_M", u_m, "um", "ΔL_m/(2√3)", rect, gum),
    ]
    u_theta = rectangular_width(tem.sensor_width_c)
    delta_t = tem.machine_temperature_c - REFERENCE_TEMPERATURE_C
    u_alpha = rectangular_width(tem.expansion_width_um_per_mm_c)
    u_mm = temperature_measurement_um(tem.expansion_um_per_mm_c, l_t, u_theta)
    u_em = expansion_coefficient_um(delta_t, l_t, u_alpha)
    u_t = root_sum_square(u_mm, tem.device_measurement_um, u_em, tem.device_expansion_um)
    lines += [
        Line("sensor", "temperature sensor", tem.sensor_width_c, "°C", "full width", none,
             "input"),
        Line("u_theta", "u(Θ)", u_theta, "°C", "width/(2√3)", rect, gum),
        Line("u_M_machine", "u_M,machine tool", u_mm, "um", "α·L_T·u(Θ)", "propagated",
             "linear expansion"),
        Line("u_M_device", "u_M,device", tem.device_measurement_um, "um", "laser's own",
             none, "input"),
        Line("T_M", "T_M", tem.machine_temperature_c, "°C", "machine temperature", none,
             "input"),
        Line("delta_T", "ΔT", delta_t, "°C", "T_M − 20 °C", none, "ISO 1"),
        Line("u_alpha", "u(α)", u_alpha, "um/(mm·°C)", "Δα/(2√3)", rect, gum),
        Line("u_E_machine", "u_E,machine tool", u_em, "um", "|ΔT|·L_T·u(α)", "propagated",
             "linear expansion"),
        Line("u_E_device", "u_E,device", tem.device_expansion_um, "um", "laser's own", none,
             "input"),
        Line("u_T", "u_T", u_t, "um", "√(u_M,mt² + u_M,dev² + u_E,mt² + u_E,dev²)",
             "combined", "GUM 5.1.2"),
    ]
    u_eve = rectangular_width(budget.environment.drift_um)
    d_ls = abbe_error_um(budget.setup.abbe_offset_mm, budget.setup.angular_deviation_um_per_m)
    u_s = rectangular_width(d_ls)
    u_p = root_sum_square(u_d, u_m, u_t, u_eve, u_s)
    lines += [
        Line("E_VE", "E_VE", budget.environment.drift_um, "um", "drift test range", none,
             "input"),
        Line("u_EVE", "u_EVE", u_eve, "um", "E_VE/(2√3)", rect, gum),
        Line("O_ABBE", "O_ABBE", budget.setup.abbe_offset_mm, "mm", "Abbe offset", none,
             "input"),
        Line("D_angle", "D_angle", budget.setup.angular_deviation_um_per_m, "um/m",
             "angular deviation gradient", none, "input"),
        Line("delta_L_S", "ΔL_S", d_ls, "um", "√2·O_ABBE·D_angle", none,
             "Abbe error; √2 from " + here),
        Line("u_S", "u_S", u_s, "um", "ΔL_S/(2√3)", rect, gum),
        Line("u_P", "u_P", u_p, "um", "√(u_D² + u_M² + u_T² + u_EVE² + u_S²)", "combined",
             "GUM 5.1.2"),
    ]
    return lines


# the um-valued lines reported as ``contributors_um`` (derived values, not inputs)
CONTRIBUTORS = ("u_accuracy", "u_wavelength", "u_device_estimate", "u_resolution", "u_D",
                "delta_L_m", "u_M", "u_M_machine", "u_M_device", "u_E_machine", "u_E_device",
                "u_T", "u_EVE", "delta_L_S", "u_S")


@dataclass
class BudgetValues:
    """A budget evaluated in one arithmetic: its lines, u_P and the expanded uncertainties."""

    arithmetic: str
    lines: list[Line]
    u_p_um: float
    expanded_um: dict = field(default_factory=dict)

    @property
    def contributors_um(self) -> dict:
        """The derived um-valued lines by key (u_D, u_M, u_T, u_EVE, u_S and their parts)."""
        return {ln.key: ln.value for ln in self.lines if ln.key in CONTRIBUTORS}


def budget_values(budget: UncertaintyBudget, arithmetic: str | None = None) -> BudgetValues:
    """``evaluate`` plus the expanded uncertainties of Table 4 (``expanded_parameters_um``)."""
    lines = evaluate(budget, arithmetic)
    v = {ln.key: ln.value for ln in lines}
    expanded = expanded_parameters_um(v["u_D"], v["u_M"], v["u_T"], v["u_EVE"], v["u_S"],
                                      budget.cycles, budget.coverage_factor)
    return BudgetValues(arithmetic or budget.arithmetic, lines, v["u_P"], expanded)


def expanded_at_length_um(budget: UncertaintyBudget, length_mm: float, cycles: int) -> dict:
    """Expanded uncertainties [um] of the ISO 230-2 figures of a test of measuring length
    ``length_mm`` [mm] and ``cycles`` runs per direction, from the contributors of ``budget``.

    The budget's ``length_mm`` and ``cycles`` are replaced by the test's own and the budget
    is evaluated in the ISO arithmetic (every length-dependent line at the test's length):
    the ``[paper]`` lengths describe one published test, not the one at hand.

    Parameters
    ----------
    budget : UncertaintyBudget
        The contributors (laser, misalignment, temperature, environment, setup) and k.
    length_mm : float
        The test's measuring length [mm] (its largest minus its smallest target); > 0.
    cycles : int
        n, the runs per direction of the test; at least 1.

    Returns
    -------
    dict
        ``R_dir``, ``B``, ``R``, ``E``, ``M``, ``A`` [um], as ``expanded_parameters_um``.
    """
    if not length_mm > 0 or cycles < 1:
        raise InputError(f"needs a measuring length > 0 and at least one run per direction; "
                         f"got {length_mm} mm and {cycles} runs", parameter="length_mm")
    return _test_values(budget, length_mm, cycles).expanded_um


def _test_values(budget: UncertaintyBudget, length_mm: float, cycles: int) -> BudgetValues:
    """The budget evaluated in the ISO arithmetic at a test's length [mm] and runs."""
    test = replace(budget, length_mm=float(length_mm), cycles=int(cycles), arithmetic="iso")
    return budget_values(test, "iso")



# --------------------------------------------------------------------------- per test
# Expanded uncertainties [um] a test carries, by the figure of ``expanded_parameters_um``.
TEST_UNCERTAINTY_KEYS = {"U_A_um": "A", "U_E_um": "E", "U_M_um": "M", "U_R_um": "R", "U_B_um": "B"}
# Standard uncertainties [um] of a test's reversal values B_i (``reversal_terms_um``).
REVERSAL_PARTS = ("u_B_setup_um", "u_B_env_um")


def per_test_um(stats, budget: UncertaintyBudget):
    """The budget evaluated at every test of per-target statistics.

    A test's measuring length is its largest minus its smallest target [mm]; its runs per
    direction n are the fewest readings any target has in either direction (dropped outliers
    lower it, which widens U). Each test gets ``expanded_at_length_um`` at (L, n) and the two
    parts of its reversal values' standard uncertainty (``reversal_terms_um``). A test with one
    target or no readings has no length to scale the budget to: its values are NaN.

    Parameters
    ----------
    stats : DataFrame
        Per-target statistics (``features.iso230.per_target``): the test keys, ``target``,
        ``n_up``, ``n_down``.
    budget : UncertaintyBudget
        The contributors and k.

    Returns
    -------
    DataFrame
        One row per test: ``machine_id``, ``axis``, ``visit``, ``test_id``, ``length_mm``
        [mm], ``cycles``, ``TEST_UNCERTAINTY_KEYS`` (k of the budget) and ``REVERSAL_PARTS`` [um].

    Raises
    ------
    InputError
        A test on a rotary axis: the budget's contributors are lengths, not angles.
    """
    import pandas as pd

    from features.readings import schema

    keys = list(schema.TEST_KEYS)
    at: dict[tuple, dict] = {}  # the budget at each (length, n): most tests share one
    rows = []
    for key, t in stats.groupby(keys, sort=False, dropna=False):
        row = dict(zip(keys, key))
        if schema.is_rotary(row["axis"]):
            raise InputError(f"test {row['test_id']} is on rotary axis {row['axis']}: an "
                             "uncertainty budget holds lengths, not angles",
                             parameter="uncertainty")
        length = float(t["target"].max() - t["target"].min())
        counts = pd.concat([t["n_up"], t["n_down"]])
        cycles = int(counts[counts > 0].min()) if (counts > 0).any() else 0
        row.update(length_mm=length, cycles=cycles)
        if length > 0 and cycles > 0:
            if (length, cycles) not in at:
                at[length, cycles] = _at_test(budget, length, cycles)
            row.update(at[length, cycles])
        rows.append(row)
    columns = [*keys, "length_mm", "cycles", *TEST_UNCERTAINTY_KEYS, *REVERSAL_PARTS]
    return pd.DataFrame(rows, columns=columns).astype(
        {c: float for c in (*TEST_UNCERTAINTY_KEYS, *REVERSAL_PARTS)})


def with_uncertainty(figures, stats, budget: UncertaintyBudget):
    """``figures`` with the ``TEST_UNCERTAINTY_KEYS`` columns [um] of every test: the budget at
    its own measuring length and runs per direction (``per_test_um``).

    Parameters
    ----------
    figures : DataFrame
        One row per test (``features.iso230.axis_figures``).
    stats : DataFrame
        The per-target statistics the figures came from (``features.iso230.per_target``).
    budget : UncertaintyBudget
        The contributors and k.

    Raises
    ------
    InputError
        A test on a rotary axis (the budget's contributors are lengths, not angles), or on
        another axis than the one the budget states (its misalignment, Abbe offset and
        temperatures are that axis's).
    """
    from features.readings import schema

    keys = list(schema.TEST_KEYS)
    per_test = per_test_um(stats, budget)  # refuses a rotary axis first
    if budget.axis:
        other = figures.loc[figures["axis"].astype(str).str.upper() != budget.axis.upper()]
        if len(other):
            row = other.iloc[0]
            raise InputError(f"the budget is written for axis {budget.axis}; test "
                             f"{row['test_id']} is of axis {row['axis']}: give that axis's "
                             "budget", parameter="uncertainty")
    return figures.merge(per_test[keys + list(TEST_UNCERTAINTY_KEYS)], on=keys, how="left")


def _at_test(budget: UncertaintyBudget, length_mm: float, cycles: int) -> dict:
    """``TEST_UNCERTAINTY_KEYS`` and ``REVERSAL_PARTS`` [um] of one test of (L, n)."""
    values = _test_values(budget, length_mm, cycles)
    u = values.contributors_um
    parts = reversal_terms_um(u["u_S"], u["u_EVE"], cycles)
    return {**{k: values.expanded_um[f] for k, f in TEST_UNCERTAINTY_KEYS.items()},
            **dict(zip(REVERSAL_PARTS, parts))}


def nominal_reversal_parts_um(budget: UncertaintyBudget) -> tuple[float, float]:
    """``REVERSAL_PARTS`` [um] at the budget's own ``length_mm`` and ``cycles``: for a test
    without a length of its own (one target)."""
    parts = _at_test(budget, budget.length_mm, budget.cycles)
    return parts[REVERSAL_PARTS[0]], parts[REVERSAL_PARTS[1]]
