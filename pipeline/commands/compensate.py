"""``backlash compensate``: controller compensation files from ISO tests or a trained predictor."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.commands.common import FORMATS

HELP = ("Write controller compensation files (LinuxCNC, SINUMERIK, Fanuc, Heidenhain, M425, "
        "grblHAL, CSV) from ISO tests or a predictor; --verify re-measures the twin with them.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
CONTROLLER_NAMES = ("linuxcnc", "siemens", "fanuc", "heidenhain", "marlin", "reprap", "grblhal",
                    "csv")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="DATA|MODEL_DIR",
                        help="readings file (ISO tests) or a model directory (backlash train)")
    parser.add_argument("--controller", required=True,
                        help=f"one or more of {', '.join(CONTROLLER_NAMES)} (comma-separated), "
                             "or all")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--format", default="auto",
                        choices=FORMATS,
                        help="input layout of DATA (default: detect)")
    parser.add_argument("--conditions", metavar="NAME=VALUE,...",
                        help="conditions for a predictor, e.g. feed_mm_min=500,machine_temp_c=21")
    parser.add_argument("--axis", default="X", help="axis name for a predictor (default X)")
    parser.add_argument("--spacing", type=float, metavar="MM",
                        help="table spacing of equidistant formats (default: a quarter of the "
                             "smallest target interval, rounded down to 1/2/2.5/5 x 10^k)")
    parser.add_argument("--reference-mm", type=float,
                        help="reference point where SINUMERIK/Fanuc/Heidenhain tables are 0 "
                             "(default: the table point nearest 0)")
    parser.add_argument("--fanuc-unit-um", type=float, default=1.0,
                        help="Fanuc detection unit [um] (default 1)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    parser.add_argument("--verify", action="store_true",
                        help="twin data only: re-run the ISO tests with the written files "
                             "applied; report before/after (verify.html); exit 3 if worse")


def controllers(text: str) -> list[str]:
    from features.readings.errors import InputError

    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    if names == ["all"]:
        return list(CONTROLLER_NAMES)
    unknown = [n for n in names if n not in CONTROLLER_NAMES]
    if unknown or not names:
        raise InputError(f"unknown controller {unknown[0] if unknown else text!r}; expected "
                         f"{', '.join(CONTROLLER_NAMES)} or all", column="--controller")
    return list(dict.fromkeys(names))


def run(args: argparse.Namespace) -> int:
    from features.readings.errors import InputError
    from features.readings.fileio import clean_nan, dumps
    from pipeline.compensation.common import Options
    from pipeline.compensation.profile import parse_conditions

    names = controllers(args.controller)
    conditions = parse_conditions(args.conditions)
    source = Path(args.source)
    if args.spacing is not None and not args.spacing > 0:
        raise InputError("must be > 0 mm", column="--spacing")
    if source.is_dir():
        if args.verify:
            raise InputError("--verify needs twin readings, not a model directory",
                             file=source, column="--verify")
        profiles = _predicted(source, conditions, args)
    else:
        if conditions:
            raise InputError("--conditions applies to a model directory, not to measured tests",
                             column="--conditions")
        from features.readings import read_readings
        from pipeline.compensation.profile import measured_profiles

        profiles = measured_profiles(read_readings(source, args.format))
    if args.verify:  # refuse before anything is written
        from pipeline.compensation.verify import twin_parameters

        twin_parameters(source)
    options = Options(args.spacing, args.reference_mm, args.fanuc_unit_um)
    written = write_all(profiles, names, Path(args.out), options)
    code, checks = 0, []
    if args.verify:
        from pipeline.compensation.report import write_report
        from pipeline.compensation.verify import closed_loop, uncompensated

        before = uncompensated(source)
        for name in names:
            files = {(r["machine_id"], r["axis"]): r["files"] for r in written
                     if r["controller"] == name}
            results = closed_loop(source, profiles, name, files, before)
            folder = Path(args.out) / "verify" / name
            report = write_report(results, name, folder)
            checks += [_check_json(r, name, report) for r in results]
        code = 0 if all(c["passed"] for c in checks) else 3
    _print_summary(profiles, written, checks)
    if args.json:
        print(dumps(clean_nan({"axes": [_profile_json(p) for p in profiles],
                               "files": [_written_json(w) for w in written],
                               "verify": checks})))
    return code


def _predicted(directory, conditions, args):
    from models.registry import load_model
    from pipeline.compensation.profile import predicted_profile

    model = load_model(directory)
    return [predicted_profile(model, conditions, args.axis.upper(), args.spacing)]


def write_all(profiles, names, out, options) -> list[dict]:
    """Every controller's files for every profile into a temporary folder first, then moved
    into ``out`` together: a user error half-way leaves nothing behind."""
    import os
    import shutil
    import tempfile

    from pipeline.compensation import CONTROLLERS

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        written = []
        for name in names:
            writer, kind = CONTROLLERS[name]
            for profile in profiles:
                result = writer(profile, tmp, options)
                result.update(controller=name, kind=kind, machine_id=profile.machine_id,
                              axis=profile.axis)
                written.append(result)
        out.mkdir(exist_ok=True)
        for path in tmp.iterdir():
            os.replace(path, out / path.name)
        for result in written:
            result["files"] = {role: out / p.name for role, p in result["files"].items()}
        return written
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _profile_json(p) -> dict:
    return {"machine_id": p.machine_id, "axis": p.axis, "source": p.source,
            "backlash_um": p.backlash, "targets_mm": p.target.tolist(),
            "mean_up_um": p.mean_up.tolist(), "mean_down_um": p.mean_down.tolist(),
            "reversal_um": p.reversal.tolist(), "notes": p.notes}


def _written_json(w) -> dict:
    out = {k: v for k, v in w.items() if k != "files"}
    out["files"] = {role: str(p) for role, p in w["files"].items()}
    return out


def _check_json(r, name, report) -> dict:
    return {"controller": name, "machine_id": r["machine_id"], "axis": r["axis"],
            "passed": r["passed"], "ratio_B": r["ratio_B"], "ratio_E": r["ratio_E"],
            "before": r["before"], "after": r["after"], "report": str(report)}


def _print_summary(profiles, written, checks) -> None:
    for p in profiles:
        print(f"{p.machine_id} {p.axis} ({p.source}): backlash {p.backlash:.3f} um, "
              f"{len(p.target)} targets", file=sys.stderr)
        for note in p.notes:
            print(f"  note: {note}", file=sys.stderr)
    for w in written:
        files = ", ".join(p.name for p in w["files"].values())
        interp = w["interpolation_error_um"]
        extra = "" if interp is None else f"; interpolation error at targets {interp:.4f} um"
        unconfirmed = (f"; not confirmed: {'; '.join(w['unconfirmed'])}"
                       if w["unconfirmed"] else "")
        print(f"{w['controller']} {w['machine_id']} {w['axis']}: {files}{extra}{unconfirmed}",
              file=sys.stderr)
    for c in checks:
        print(f"verify {c['controller']} {c['machine_id']} {c['axis']}: "
              f"{'passed' if c['passed'] else 'FAILED'}; B {c['before']['B']:.3f} -> "
              f"{c['after']['B']:.3f} um, E {c['before']['E']:.3f} -> {c['after']['E']:.3f} um "
              f"-> {c['report']}", file=sys.stderr)
