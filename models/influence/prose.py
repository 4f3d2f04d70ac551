"""The physical reading of each verdict, in words, from the effect records."""

from __future__ import annotations

import numpy as np
import pandas as pd

from models.influence.design import LEVEL_WORDS, Design
from models.influence.paths import LABELS, Path


def physical_reading(name: str, row: pd.Series, path: Path, design: Design,
                     unit: str = "um") -> str:
    """One or two sentences: the verdict and the physics behind it, from the effect records;
    effects in ``unit`` (um, or arcsec on rotary axes)."""
    label = LABELS.get(name, name)
    verdict, proxy = row["verdict"], row["proxy_for"]
    via = "; ".join(f"{n}: {r}" for n, r in path.paths)
    position = "; ".join(f"{n}: {r}" for n, r in path.position)
    where = LEVEL_WORDS.get(row["level"], "")
    if verdict == "driver":
        interval = f"{row['effect_low_um']:.2f}-{row['effect_high_um']:.2f}"
        return (f"{label} drives backlash: {row['effect_um']:.2f} {unit} over the observed "
                f"range (95 % interval {interval} {unit}, {row['effect_shape']}), given the other inputs "
                f"({_p_text(row['p_value'])}, tested {LEVEL_WORDS[row['tested']]}). "
                f"Physical path: {via}.")
    if verdict == "undecided":
        return (f"{label} cannot be decided in this design: it varies only {where} and leaves "
                "no residual degrees of freedom there; " + _separation(name, design))
    if verdict == "proxy":
        if proxy == "backlash_um":
            return (f"{label} stands in for the backlash itself: the target is computed from "
                    "the same linear test, so the input carries the target's own measurement "
                    "(and the position-dependent errors of the axis), not a cause.")
        if proxy in ("visit", "run"):
            text = (f"{label} stands in for the {proxy}: it changed only {where}, so its "
                    f"association measures whatever else changed between {proxy}s, not an "
                    "effect of its own")
        elif proxy:
            text = (f"{label} follows {LABELS.get(proxy, proxy).lower()} in this test plan, "
                    f"and its association with backlash is that of "
                    f"{LABELS.get(proxy, proxy).lower()}")
        else:
            text = (f"{label} carries structure that the recorded effects do not explain; an "
                    "effect missing from the model may follow it (backlash discover)")
        if path.paths:
            text += f" (its own path, {via}, is not significant given the others)"
        elif position:
            text += f". It acts on the measured position only: {position}"
        else:
            text += ". No effect record gives it a path to lost motion"
        return text + "."
    if path.paths:
        return (f"{label} has no measurable influence given the other inputs "
                f"({_p_text(row['p_value'])}; effect at most {row['effect_high_um']:.2f} {unit} "
                f"over the observed range). Possible path: {via}.")
    tail = f" It acts on the measured position only: {position}." if position else \
        " No effect record gives it a path to lost motion."
    return f"{label} has no measurable influence on backlash.{tail}"


def _p_text(p) -> str:
    if not np.isfinite(p):
        return "p n/a"
    return f"p = {p:.2g}" if p >= 1e-4 else "p < 1e-4"


def _separation(name: str, design: Design) -> str:
    tests = sorted((c for c in design.confounded if name in c["inputs"]),
                   key=lambda c: "visit" not in c["inputs"])
    return tests[0]["separating_test"] + "." if tests else \
        "vary it independently of the other inputs."

