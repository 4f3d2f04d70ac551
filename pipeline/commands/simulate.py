"""``backlash simulate``: the feed-drive twin writes a readings table and its truth."""

from __future__ import annotations

import argparse
import sys

HELP = "Simulate ISO 230-2 test campaigns on the feed-drive twin; write readings and truth."
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", default="paper",
                        help="paper, fleet, drift, demo or indirect (default paper)")
    parser.add_argument("--config", metavar="FILE.toml",
                        help="campaign configuration; overrides the preset's values")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--out", required=True, help="output folder")


def run(args: argparse.Namespace) -> int:
    from features.readings.errors import InputError
    from models.physics.campaign import PRESETS, load_config, simulate

    if args.preset not in PRESETS:
        raise InputError(f"unknown preset {args.preset!r}; expected one of "
                         f"{', '.join(PRESETS)}", column="--preset")
    config = (load_config(args.config, preset=args.preset) if args.config
              else load_config(args.preset))
    sim = simulate(config, args.seed)
    write(sim, args.out)
    print(f"{len(sim.readings)} readings in {sim.readings['test_id'].nunique()} tests "
          f"({config['system']} measuring system) -> {args.out}/readings.csv, truth.csv, "
          "truth_visits.csv, parameters.json", file=sys.stderr)
    return 0


def write(sim, out_dir) -> None:
    """All four files into a temporary folder, then renamed into place together."""
    import os
    import shutil
    from pathlib import Path

    from features.readings import write_readings
    from features.readings.fileio import temp_folder, write_json

    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_folder(out)
    try:
        write_readings(sim.readings, tmp / "readings.csv")
        sim.truth.to_csv(tmp / "truth.csv", index=False)
        sim.visits.to_csv(tmp / "truth_visits.csv", index=False)
        write_json(tmp / "parameters.json", sim.parameters)
        out.mkdir(exist_ok=True)
        for path in tmp.iterdir():
            os.replace(path, out / path.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
