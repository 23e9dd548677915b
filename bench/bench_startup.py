"""Benchmark of the command line's start: ``camcal --help`` and ``camcal lrm --help`` against starting Python.

Prints wall times (median of several runs, each a fresh interpreter) beside
the floor, ``python -c pass`` in the same run, and the heaviest imports of
``import camcal.cli`` (``python -X importtime``, cumulative microseconds).

Run: ``.venv/bin/python bench/bench_startup.py [--runs N]``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def wall(cmd: list[str], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


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
    print("| figure | time | floor (`python -c pass`) | aim |")
    print("| --- | --- | --- | --- |")
    print(f"| `camcal --help` | {help_all:.3f} s | {floor:.3f} s | <= 0.3 s |")
    print(f"| `camcal lrm --help` | {help_lrm:.3f} s | {floor:.3f} s | <= 0.3 s |")
    print()
    print("`python -X importtime -c 'import camcal.cli'`, heaviest (cumulative) first:")
    print()
    print("| module | cumulative | self |")
    print("| --- | --- | --- |")
    for own, cumulative, name in import_times("camcal.cli")[:10]:
        print(f"| `{name.strip()}` | {cumulative / 1e3:.1f} ms | {own / 1e3:.1f} ms |")


if __name__ == "__main__":
    main()
