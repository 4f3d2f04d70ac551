"""Run every benchmark module in this folder, one after the other, on the same machine."""

import importlib
import pkgutil
import sys
from pathlib import Path

from bench import TINY, TINY_NOTE

if __name__ == "__main__":
    names = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])
                   if m.name.startswith("bench_"))
    wanted = sys.argv[1:]
    unknown = set(wanted) - {name.removeprefix("bench_") for name in names}
    if unknown:  # a misspelt name would otherwise run nothing and succeed
        sys.exit(f"no bench module named {', '.join(sorted(unknown))}")
    if TINY:
        print(TINY_NOTE, flush=True)
    for name in names:
        if wanted and name.removeprefix("bench_") not in wanted:
            continue
        print(f"== {name.removeprefix('bench_')}", flush=True)
        importlib.import_module(f"bench.{name}").main()
