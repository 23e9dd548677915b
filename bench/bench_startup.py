"""Benchmark of the command line's start: ``camcal --help`` and ``camcal lrm --help`` against starting Python.

Prints wall times (median of several runs, each a fresh interpreter) beside
the floor, ``python -c pass`` in the same run, and the heaviest imports of
``import camcal.cli`` (``python -X importtime``, cumulative microseconds).

Run: ``.venv/bin/python bench/bench_startup.py [--runs N]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def wall(cmd: list[str], runs: int) -> tuple[float, float]:
    """Median wall time and median CPU time (user + system) of ``runs`` runs of ``cmd``.

    The CPU time is what the command costs whatever else runs on the machine;
    the wall time also holds the waits for a core when other jobs have them.
    """
    times, cpu = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
        times.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(times), statistics.median(cpu)


def import_times(module: str) -> list[tuple[int, int, str]]:
    """(self µs, cumulative µs, module) of every import ``import module`` makes, heaviest first."""
    out = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", f"import {module}"],
        check=True,
        capture_output=True,
        text=True,
        cwd=ROOT,
    ).stderr
    rows = []
    for line in out.splitlines():
        if not line.startswith("import time:") or "|" not in line or "self [us]" in line:
            continue
        own, cumulative, name = line[len("import time:") :].split("|")
        rows.append((int(own), int(cumulative), name.rstrip()))
    return sorted(rows, key=lambda r: -r[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="runs per figure (median)")
    args = parser.parse_args()
    py = sys.executable
    floor = wall([py, "-c", "pass"], args.runs)
    help_all = wall([py, "-m", "camcal", "--help"], args.runs)
    help_lrm = wall([py, "-m", "camcal", "lrm", "--help"], args.runs)
    print("| figure | time | CPU time | floor (`python -c pass`): time, CPU | aim |")
    print("| --- | --- | --- | --- | --- |")
    for name, (t, cpu) in (("camcal --help", help_all), ("camcal lrm --help", help_lrm)):
        print(f"| `{name}` | {t:.3f} s | {cpu:.3f} s | {floor[0]:.3f} s, {floor[1]:.3f} s | <= 0.3 s |")
    print(f"\n(load average {os.getloadavg()[0]:.1f} at the end)")
    print()
    print("`python -X importtime -c 'import camcal.cli'`, heaviest (cumulative) first:")
    print()
    print("| module | cumulative | self |")
    print("| --- | --- | --- |")
    for own, cumulative, name in import_times("camcal.cli")[:10]:
        print(f"| `{name.strip()}` | {cumulative / 1e3:.1f} ms | {own / 1e3:.1f} ms |")


if __name__ == "__main__":
    main()
