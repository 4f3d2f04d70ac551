"""Run every benchmark module in this folder, one after the other, on the same machine."""

import importlib
import pkgutil
import resource
import sys
import time
from pathlib import Path

from bench import TINY, TINY_NOTE


def _cpu() -> float:
    """CPU seconds of this process and of the commands it ran and waited for: a section's
    cost that other work on the machine does not inflate as much as its wall time."""
    return sum(resource.getrusage(who).ru_utime + resource.getrusage(who).ru_stime
               for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))


if __name__ == "__main__":
    names = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])
                   if m.name.startswith("bench_"))
    wanted = sys.argv[1:]
    unknown = set(wanted) - {name.removeprefix("bench_") for name in names}
    if unknown:  # a misspelt name would otherwise run nothing and succeed
        sys.exit(f"no bench module named {', '.join(sorted(unknown))}")
    if TINY:
        print(TINY_NOTE, flush=True)
    started, cpu_started = time.perf_counter(), _cpu()
    for name in names:
        if wanted and name.removeprefix("bench_") not in wanted:
            continue
        print(f"== {name.removeprefix('bench_')}", flush=True)
        begun, cpu_begun = time.perf_counter(), _cpu()
        importlib.import_module(f"bench.{name}").main()
        print(f"-- {name.removeprefix('bench_')}: {time.perf_counter() - begun:.1f} s wall, "
              f"{_cpu() - cpu_begun:.1f} s CPU", flush=True)
    print(f"-- total: {time.perf_counter() - started:.1f} s wall, "
          f"{_cpu() - cpu_started:.1f} s CPU", flush=True)
