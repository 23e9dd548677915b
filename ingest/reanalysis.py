"""Re-analysing stored frames with other calibration inputs, beside the original results.

A re-analysis is a new analysis run of a dive: per-frame results, the
per-visit λ_att series and the linearity fits, computed as the live ingest
computes them. The per-frame work is `ingest.worker.analyse_batch` mapped
over batches of frames by a runner (`ingest.runners`: in this process, a
local process pool, or Dask), with the frames read through fsspec; the
results are stored by this process (the one writer) as batches complete.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

from analysis import FrameConfig
from camcal.core import __version__
from camcal.core.calibrations import setup_of
from camcal.core.frameset import FrameSetError, Setup, parse_setup
from camcal.core.parallel import process_pool
from ingest.derived import linearity_rows, mean_gray_by_setting, result_row
from ingest.results import crashed_row
from ingest.rolling import Sample, series_rows
from ingest.runners import BatchRunner, LocalRunner
from ingest.worker import analyse_batch
from storage import queries
from storage.queries.runs import RUN_BEAT_S
from storage.store import Store

log = logging.getLogger("camcal.reanalysis")


@dataclass(frozen=True)
class ReanalysisOptions:
    """How a re-analysis runs.

    ``reuse_live``: when the linear range is the live run's, each frame's
    I_center is unchanged, so its live result is copied instead of analysed
    again. ``frames_url``: where the data folder's frame files are read from
    if not the data folder itself (a mirror in object storage, e.g.
    ``s3://bucket/camcal-data``), with fsspec ``storage_options``.
    ``t_from``/``t_to``: only frames captured in that span (UTC seconds).
    """

    workers: int = 1
    batch_size: int = 16
    reuse_live: bool = True
    frames_url: str | None = None
    storage_options: Mapping[str, Any] = field(default_factory=dict)
    t_from: float | None = None
    t_to: float | None = None


def start_run(
    store: Store, dive_id: int, setup: Setup, label: str = "", calibration_id: int | None = None
) -> int:
    """A new re-analysis run of a dive (status ``running``, no results yet); returns its id."""
    run = store.analysis_run(
        dive_id,
        "reanalysis",
        label=label,
        calibration=setup.to_json(),
        calibration_id=calibration_id,
        software_version=__version__,
    )
    assert run is not None
    return run.id


class ReanalysisInterrupted(Exception):
    """The re-analysis was asked to stop (its server stops): the run is marked ``interrupted``."""


class RunBeats:
    """Says every `RUN_BEAT_S` that the runs it holds are still queued or running.

    A run nobody beats for `storage.queries.runs.RUN_STALE_S` reads as ``interrupted``: the
    process that held it was stopped (killed, the machine down) without ending it, and it would
    otherwise read as running forever. A beat the database refuses is logged and tried again.
    """

    def __init__(self, store: Store, run_ids: Sequence[int] = ()) -> None:
        self.store = store
        self._ids = set(run_ids)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="run-beats", daemon=True)
        self._thread.start()

    def hold(self, run_id: int) -> None:
        with self._lock:
            self._ids.add(run_id)

    def release(self, run_id: int) -> None:
        with self._lock:
            self._ids.discard(run_id)

    def _beat(self) -> None:
        while not self._stop.wait(RUN_BEAT_S):
            with self._lock:
                ids = sorted(self._ids)
            try:
                self.store.beat_runs(ids)
            except Exception as exc:  # the database away for a moment: the next beat tries again
                log.warning("could not say that runs %s are still under way: %s", ids, exc)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


@contextlib.contextmanager
def beating(store: Store, run_id: int) -> Iterator[None]:
    beats = RunBeats(store, [run_id])
    try:
        yield
    finally:
        beats.stop()


class ReanalysisInputError(ValueError):
    """A re-analysis cannot start: an unknown calibration, or inputs that make no valid setup."""


class UnknownCalibration(ReanalysisInputError):
    """No stored calibration by that reference."""


@dataclass(frozen=True)
class StartedReanalysis:
    run_id: int
    setup: Setup
    label: str
    record: dict[str, Any] | None  # the stored calibration it uses, if one was named


def find_calibration(store: Store, ref: int | str) -> dict[str, Any]:
    """A stored calibration by id, ``name`` (its newest version valid now) or ``name@version``;
    `UnknownCalibration` (naming what is stored) if there is none."""
    record = store.call(queries.calibration, ref)
    if record is None:
        known = sorted({f"{c['name']}@{c['version']}" for c in store.call(queries.calibrations)})
        raise UnknownCalibration(
            f"no calibration {ref!r} in the store (stored: {', '.join(known) or 'none'})"
        )
    return record


def base_setup(store: Store, dive_id: int) -> Setup:
    """The calibration a dive was analysed with: its live run's, else the dive's own setup (an
    imported dive), else the default (T-REX). Never an earlier re-analysis's: each starts from the
    dive's own inputs, so two re-analyses with different overrides do not compound."""
    return stored_setup(store, dive_id) or Setup()


def stored_setup(store: Store, dive_id: int) -> Setup | None:
    """The live run's calibration, else the dive's own setup; None if neither holds one."""
    with store.read() as s:
        live = next((r for r in queries.runs(s, dive_id, count_results=False) if r["kind"] == "live"), None)
        cal = queries.calibration_in_force(s, dive_id, live or {})
    if not cal:
        return None
    try:
        return parse_setup(cal, f"dive {dive_id}")
    except FrameSetError:
        return Setup()


def start_reanalysis(
    store: Store,
    dive_id: int,
    *,
    actor: str,
    default_label: str,
    label: str | None = None,
    calibration: int | str | None = None,
    setup: Setup | None = None,
    adjust: Callable[[Setup], Setup] | None = None,
    what: str = "",
) -> StartedReanalysis:
    """Start a re-analysis of a dive, as the API and ``camcal reanalyze`` both do.

    The setup: the stored ``calibration`` record's (by id, ``name`` or
    ``name@version``), else ``setup``, else the one the dive was analysed
    with (`base_setup`); then ``adjust`` (the caller's overrides: distances,
    I0'/I0, linear range). The run is labelled ``label``, else after the
    calibration record (and ``what``), else ``default_label``; its start is audited as
    ``actor``. Raises `ReanalysisInputError` for an unknown calibration or
    inputs that make no valid setup. The run is left for `reanalyse` to fill.
    """
    record = find_calibration(store, calibration) if calibration is not None else None
    try:
        chosen = setup_of(record) if record else (setup or base_setup(store, dive_id))
        final = adjust(chosen) if adjust else chosen
    except (FrameSetError, ValueError) as exc:
        raise ReanalysisInputError(str(exc)) from None
    if not label:
        label = f"calibration {record['name']} v{record['version']}{what}" if record else default_label
    cal_id = record["id"] if record else None
    run_id = start_run(store, dive_id, final, label, cal_id)
    store.audit(
        actor,
        "reanalysis.start",
        f"dive:{dive_id}",
        {"run_id": run_id, "calibration_id": cal_id, "calibration": final.to_json()},
    )
    return StartedReanalysis(run_id, final, label, record)


def reanalyse(
    store: Store,
    dive_id: int,
    run_id: int,
    setup: Setup,
    options: ReanalysisOptions | None = None,
    progress: Callable[[str, float], None] | None = None,
    runner: BatchRunner | None = None,
    sources: Mapping[int, str] | None = None,
    cancel: threading.Event | None = None,
) -> int:
    """Fill run ``run_id`` of a dive: frame results, the λ_att series and linearity.

    Frames are analysed again on ``runner`` (default: a local pool of
    ``options.workers`` processes) unless their live results can be reused
    (see `ReanalysisOptions`). With ``sources`` (frame id -> URL), exactly
    those frames are analysed, each read from its URL (e.g. the frame-set
    folder it was imported from). Distances and emission ratios only enter
    λ_att, which is always recomputed. The live run is never touched. The
    run ends ``done``, or ``failed`` re-raising, or ``interrupted`` when
    ``cancel`` is set (between batches: `ReanalysisInterrupted`) or on
    KeyboardInterrupt. While it runs it beats (`RunBeats`). Returns the
    number of frame results.
    """
    options = options or ReanalysisOptions()
    with beating(store, run_id):
        return _reanalyse(store, dive_id, run_id, setup, options, progress, runner, sources, cancel)


def _reanalyse(
    store: Store,
    dive_id: int,
    run_id: int,
    setup: Setup,
    options: ReanalysisOptions,
    progress: Callable[[str, float], None] | None,
    runner: BatchRunner | None,
    sources: Mapping[int, str] | None,
    cancel: threading.Event | None,
) -> int:
    live = store.analysis_run(dive_id, "live", create=False)
    try:
        same_range = live is not None and tuple(live.calibration.get("linear_range", ())) == tuple(
            setup.linear_range
        )
        if progress:
            progress("frames", 0.0)
        if sources is None and same_range and live is not None and options.reuse_live:
            n = store.copy_results(live.id, run_id, options.t_from, options.t_to)
        else:
            if sources is not None:
                tasks = sorted(sources.items())
            else:
                tasks = [
                    (fid, store.files.url(path, options.frames_url))
                    for fid, path in store.call(queries.dive_frames, dive_id, options.t_from, options.t_to)
                ]
            modules = store.call(queries.frame_modules, [fid for fid, _ in tasks])
            configs = {m: FrameConfig(**setup.frame_settings(m)) for m in set(modules.values())}
            configs[""] = FrameConfig(**setup.frame_settings(None))
            n = analyse_into_run(
                store,
                run_id,
                [(fid, url, modules.get(fid, "")) for fid, url in tasks],
                configs,
                options,
                runner or LocalRunner(options.workers),
                progress=(lambda f: progress("frames", 0.7 * f)) if progress else None,
                cancel=cancel,
            )
        if progress:
            progress("attenuation", 0.7)
        derive_run(store, dive_id, run_id, setup)
        store.finish_run(run_id, "done", n)
        if progress:
            progress("done", 1.0)
        return n
    except (ReanalysisInterrupted, KeyboardInterrupt):
        log.warning("re-analysis %s of dive %s interrupted: start it again to complete it", run_id, dive_id)
        store.finish_run(run_id, "interrupted")
        raise
    except BaseException:
        log.exception("re-analysis %s of dive %s failed", run_id, dive_id)
        store.finish_run(run_id, "failed")
        raise


def analyse_into_run(
    store: Store,
    run_id: int,
    tasks: Sequence[tuple[int, str] | tuple[int, str, str]],
    config: FrameConfig | Mapping[str, FrameConfig],
    options: ReanalysisOptions,
    runner: BatchRunner,
    progress: Callable[[float], None] | None = None,
    analyse: Callable[..., list[tuple[int, dict[str, Any]]]] = analyse_batch,
    cancel: threading.Event | None = None,
) -> int:
    """Analyse frames ``(frame_id, URL or path[, module])`` in batches on ``runner`` (with ``config``,
    or its module's when it maps modules to configs, see `analyse_batch`); store each batch's
    results as it completes. Returns the number of results stored.

    When an analysis process dies (the OOM killer, a decoder crash), the frames not yet done are
    analysed one at a time, as the live ingest does (`one_at_a_time`): a run is not lost to it.
    ``analyse`` is `ingest.worker.analyse_batch` (another only in tests: a frame that kills).
    With ``cancel`` set, `ReanalysisInterrupted` is raised after the batch being stored.
    """
    size = max(1, options.batch_size)
    batches = [tasks[i : i + size] for i in range(0, len(tasks), size)]
    stored = done = 0
    storage_options = dict(options.storage_options)
    finished: set[int] = set()

    def keep(out: list[tuple[int, dict[str, Any]]]) -> None:
        nonlocal stored, done
        t = time.time()
        rows = []
        for fid, row in out:
            for k in ("analysis_s", "width_px", "height_px"):
                row.pop(k, None)
            rows.append({**row, "frame_id": fid, "analysed_unix_s": t})
        stored += store.save_results(run_id, rows)
        done += len(rows)
        finished.update(fid for fid, _ in out)
        if progress:
            progress(done / max(1, len(tasks)))
        if cancel is not None and cancel.is_set():
            raise ReanalysisInterrupted(f"run {run_id} stopped after {done} of {len(tasks)} frames")

    try:
        for out in runner.map(analyse, batches, config=config, storage_options=storage_options):
            keep(out)
    except Exception as exc:
        if not worker_died(exc):
            raise
        rest = [t for t in tasks if t[0] not in finished]
        log.error(
            "re-analysis run %s: an analysis process died (%s); its %d frames still to do are analysed "
            "one at a time, and a frame that kills its process alone is stored as rejected",
            run_id,
            type(exc).__name__,
            len(rest),
        )
        one_at_a_time(rest, config, storage_options, keep, analyse)
    return stored


def worker_died(exc: BaseException) -> bool:
    """Whether ``exc`` says a worker process died (a local pool, or Dask's ``KilledWorker``)."""
    return isinstance(exc, BrokenProcessPool) or type(exc).__name__ == "KilledWorker"


def one_at_a_time(
    tasks: Sequence[tuple[int, str] | tuple[int, str, str]],
    config: FrameConfig | Mapping[str, FrameConfig],
    storage_options: dict[str, Any],
    keep: Callable[[list[tuple[int, dict[str, Any]]]], None],
    analyse: Callable[..., list[tuple[int, dict[str, Any]]]] = analyse_batch,
) -> None:
    """Analyse ``tasks`` one at a time in a process of their own (replaced when it dies, as the
    live ingest does): a frame that kills it is the cause for certain, stored as ``analysis_crashed``."""
    pool = process_pool(1)
    try:
        for task in tasks:
            try:
                keep(pool.submit(analyse, [task], config, storage_options).result())
            except BrokenProcessPool:
                log.error("frame %s killed an analysis process on its own: stored as rejected", task[0])
                keep([(task[0], crashed_row())])
                pool.shutdown(wait=False)
                pool = process_pool(1)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def derive_run(store: Store, dive_id: int, run_id: int, setup: Setup) -> int:
    """The per-visit λ_att series and the linearity fits of a run, from its stored frame results.

    The series is the one the live ingest builds from the same frames
    (`ingest.rolling`), every visit final; visits the run held that these
    frames no longer make (two visits joined by frames an import added) are
    deleted. Returns the number of visits.
    """
    rows = store.call(queries.result_rows, run_id, dive_id)
    try:
        points = series_rows((Sample.from_result(r) for r in rows), setup)
    except ValueError:  # fewer than two cameras with distances: no series
        points = []
    gone = store.call(queries.visit_keys, run_id) - {str(p["visit_key"]) for p in points}
    store.save_visit_points(
        run_id, [{**p, "run_id": run_id, "dive_id": dive_id} for p in points], sorted(gone)
    )
    result_rows = [result_row(r) for r in rows]
    lr = tuple(setup.linear_range)
    store.upsert_linearity(
        [
            {**row, "run_id": run_id, "module_id": module, "wavelength_nm": wl, "updated_unix_s": time.time()}
            for (module, wl), pts in mean_gray_by_setting(result_rows).items()
            for row in linearity_rows(pts, lr)  # type: ignore[arg-type]
        ]
    )
    return len(points)
