"""Re-analysis on Dask: frames/s of a stored dive re-analysed on 1 and 2 workers.

Builds a 5 MP T-REX frame set (both cameras, three wavelengths), imports it
into a fresh store (a dive), then re-analyses every frame again (no reuse of
earlier results) on a `distributed.LocalCluster` of 1 and of 2 worker
processes, frames read through fsspec. The clusters are started and warmed
(imports done) before the clock runs; the time covers reading, decoding,
analysing, storing the results, the λ_att series and the linearity fits.
In-process (no Dask) is measured beside them as the floor of the overhead.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_reanalyze.py [--repeats 4] [--batch-size 8]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from camcal.core.schedule import Schedule
from ingest.importer import import_frame_set
from ingest.reanalysis import ReanalysisOptions, reanalyse, start_run
from ingest.runners import DaskRunner, LocalRunner
from lrm.simset import SimulationSpec, simulate_frame_set
from storage.store import Store


def timed_run(store: Store, dive_id: int, setup, runner, batch_size: int) -> tuple[int, float, float]:
    """Frames, wall seconds, and CPU seconds of this process (all of it for the in-process runner)."""
    run_id = start_run(store, dive_id, setup, "bench")
    opts = ReanalysisOptions(reuse_live=False, batch_size=batch_size)
    t0, c0 = time.perf_counter(), time.process_time()
    n = reanalyse(store, dive_id, run_id, setup, opts, runner=runner)
    return n, time.perf_counter() - t0, time.process_time() - c0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--repeats", type=int, default=4, help="frames per setting (x 2 cameras, 3 wl, 3 settings)"
    )
    parser.add_argument("--batch-size", type=int, default=8, help="frames per Dask task")
    parser.add_argument("--rounds", type=int, default=2, help="re-analyses per configuration (best is kept)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "set"
        sched = Schedule(name="bench", exposures_s=(0.05, 0.07, 0.11), gains_db=(6.0,), repeats=args.repeats)
        spec = SimulationSpec(schedule=sched, seed=11)
        print(f"building a 5 MP frame set of {sched.n_frames * 2} frames ...", flush=True)
        simulate_frame_set(folder, spec)
        store = Store.open(Path(tmp) / "data", sqlite_synchronous="NORMAL")
        dive = store.open_dive("bench", spec.setup().to_json())
        report = import_frame_set(store, folder, dive_id=dive.id, analyse=False)
        n_frames = report.imported
        mb = sum(p.stat().st_size for p in folder.glob("*.png")) / max(1, n_frames) / 1e6
        print(f"{n_frames} frames of 2448x2048, {mb:.2f} MB PNG each; {os.cpu_count()} cores", flush=True)
        setup = spec.setup()
        rows = []
        for label, make in (
            ("in-process", lambda: LocalRunner(1)),
            ("dask, 1 worker", lambda: DaskRunner(workers=1)),
            ("dask, 2 workers", lambda: DaskRunner(workers=2)),
        ):
            runner = make()
            try:
                best = min(
                    (timed_run(store, dive.id, setup, runner, args.batch_size) for _ in range(args.rounds)),
                    key=lambda r: r[1],
                )
            finally:
                runner.close()
            rows.append((label, best[0], best[1]))
            cpu = f"; {1e3 * best[2] / best[0]:.0f} ms CPU per frame" if label == "in-process" else ""
            print(
                f"{label:>16}: {best[0]} frames in {best[1]:.2f} s = {best[0] / best[1]:.1f} frames/s{cpu}",
                flush=True,
            )
        base = rows[1][2]
        print(f"2 workers vs 1: {base / rows[2][2]:.2f}x faster; load average {os.getloadavg()[0]:.1f}")
        store.close()


if __name__ == "__main__":
    main()
