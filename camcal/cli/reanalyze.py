"""``camcal reanalyze``: analyse stored frames again with another calibration, on Dask."""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from camcal.cli.common import DataOption, DbUrlOption, console, err_console, fail, labelled
from camcal.cli.overrides import (
    ClockOffsetOption,
    DistanceErrOption,
    DistanceOption,
    LinearRangeOption,
    RatioOption,
    overrides_from,
)
from camcal.core.files import write_atomic

if TYPE_CHECKING:
    from camcal.core.frameset import Setup


def register(app: typer.Typer) -> None:
    app.command("reanalyze")(reanalyze)


def parse_time(text: str | None, option: str) -> float | None:
    """ISO 8601 (``2026-11-20T10:00:00Z``; no zone means UTC) -> UNIX seconds."""
    if text is None:
        return None
    from camcal.core.utctime import parse_utc_unix_s

    try:
        return parse_utc_unix_s(text)
    except ValueError as exc:
        raise fail(f"{option}: {exc} (no zone means UTC)") from None


def parse_storage_options(items: list[str] | None) -> dict[str, Any]:
    """``["endpoint_url=http://127.0.0.1:9000", "anon=false"]`` -> fsspec keyword arguments."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise fail(f"--storage-option: expected KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def load_setup_file(path: Path) -> Setup:
    from camcal.core.frameset import FrameSetError, parse_setup

    try:
        return parse_setup(json.loads(path.read_text(encoding="utf-8")), str(path))
    except OSError as exc:
        raise fail(f"--setup: cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise fail(f"--setup: {path} is not valid JSON ({exc})") from None
    except FrameSetError as exc:
        raise fail(f"--setup: {exc}") from None


def reanalyze(
    folders: Annotated[
        list[str] | None,
        typer.Argument(
            help="Frame-set folders or URLs (s3://bucket/prefix) to import into the store and re-analyse."
        ),
    ] = None,
    dive: Annotated[
        str | None,
        typer.Option(
            help="The stored dive to re-analyse (by name); with folders, the dive to import them into "
            "(default: the folder's name)."
        ),
    ] = None,
    t_from: Annotated[
        str | None, typer.Option("--from", help="Only frames captured from this UTC time (ISO 8601).")
    ] = None,
    t_to: Annotated[
        str | None, typer.Option("--to", help="Only frames captured up to this UTC time (ISO 8601).")
    ] = None,
    setup: Annotated[
        Path | None,
        typer.Option(
            help="setup.json with the calibration (default: the one the frames were analysed with)."
        ),
    ] = None,
    calibration: Annotated[
        str | None,
        typer.Option(
            help="A stored calibration record: NAME (its newest version valid now), NAME@VERSION or its id "
            "(`camcal calibration list`). The new run records it."
        ),
    ] = None,
    distance: DistanceOption = None,
    distance_err: DistanceErrOption = None,
    ratio: RatioOption = None,
    linear_range: LinearRangeOption = None,
    clock_offset: ClockOffsetOption = None,
    data: DataOption = None,
    db_url: DbUrlOption = None,
    frames_url: Annotated[
        str | None,
        typer.Option(
            help="Read the store's frame files from this copy of the data folder (s3://bucket/camcal-data) "
            "instead of the data folder."
        ),
    ] = None,
    storage_option: Annotated[
        list[str] | None,
        typer.Option(help="fsspec option for URLs, KEY=VALUE (e.g. endpoint_url=http://host:9000)."),
    ] = None,
    workers: Annotated[int, typer.Option(help="Worker processes of the local Dask cluster.")] = 2,
    scheduler: Annotated[
        str | None,
        typer.Option(help="A running Dask scheduler (tcp://host:8786) instead of a local cluster."),
    ] = None,
    batch_size: Annotated[int, typer.Option(help="Frames per Dask task.")] = 16,
    reuse_live: Annotated[
        bool,
        typer.Option(
            help="Copy the live results when the linear range is unchanged (λ_att is recomputed either way)."
        ),
    ] = True,
    label: Annotated[str | None, typer.Option(help="A label for the new analysis run.")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write a summary as JSON here.")] = None,
) -> None:
    """Re-analyse a stored dive, a time span, or frame-set folders with another calibration, on Dask.

    The results go into the store as a new analysis run beside the originals
    (the live run is never changed): per-frame I_center, the per-visit λ_att
    series (visits cut as the setup's ``series`` section says; the live
    run's by default, so an unchanged calibration gives the live series) and
    the linearity fits. Frames are read through fsspec, so a
    folder and an S3-compatible bucket work the same.
    """
    from camcal.cli.data import open_store
    from ingest.reanalysis import ReanalysisOptions

    frm, to = parse_time(t_from, "--from"), parse_time(t_to, "--to")
    if frm is not None and to is not None and frm > to:
        raise fail("--from must not be later than --to")
    if folders and (frm is not None or to is not None):
        raise fail("give frame-set folders or a time span (--from/--to), not both")
    if not folders and dive is None and frm is None and to is None:
        raise fail("say what to re-analyse: --dive NAME, --from/--to, or frame-set folders")
    if folders and frames_url:
        raise fail("--frames-url is for a stored dive's frames; folders are read where they are")
    if workers < 1 or batch_size < 1:
        raise fail("--workers and --batch-size must be at least 1")
    if setup and calibration:
        raise fail("give --setup or --calibration, not both")
    overrides = overrides_from(distance, distance_err, ratio, linear_range, clock_offset)
    chosen = load_setup_file(setup) if setup else None
    storage_options = parse_storage_options(storage_option)
    options = ReanalysisOptions(
        batch_size=batch_size,
        reuse_live=reuse_live,
        frames_url=frames_url,
        storage_options=storage_options,
        t_from=frm,
        t_to=to,
    )

    store = open_store(data, db_url, create=bool(folders))
    cancel = _stop_on_signals()
    runner = None
    summaries: list[dict[str, Any]] = []
    try:
        if calibration:
            _check_calibration(store, calibration)
        jobs = (
            _import_folders(store, folders, dive, storage_options)
            if folders
            else _stored(store, dive, frm, to)
        )
        if not jobs:
            raise fail("no stored frames match (check --dive, --from and --to)")
        runner = _start_runner(workers, scheduler)
        for job in jobs:
            started = _start(store, job, chosen, overrides.apply, label, calibration, options)
            summaries.append(_run(store, job, started, options, runner, cancel))
    finally:
        if runner is not None:
            runner.close()
        store.close()
    _print(summaries)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(json_out, (json.dumps({"runs": summaries}, indent=1) + "\n").encode(), fsync=False)
        console.print(f"wrote {json_out}")


def _stop_on_signals() -> threading.Event:
    """Ctrl-C or SIGTERM (`kill`, systemd) stop the run after the batch it stores, marked
    ``interrupted``; a second Ctrl-C stops at once."""
    cancel = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if cancel.is_set():
            raise KeyboardInterrupt
        cancel.set()
        err_console.print("stopping after the batch under way (Ctrl-C again to stop at once)")

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return cancel


def _stored(store: Any, name: str | None, frm: float | None, to: float | None) -> list[dict[str, Any]]:
    """A job per dive: the named one, or every dive with frames in the span."""
    from storage import queries

    if name is not None:
        d = store.call(queries.dive_by_name, name)
        if d is None:
            raise fail(f"--dive: no dive named {name!r} in the store")
        dives = [d]
    else:
        dives = store.call(queries.dives_with_frames, frm, to)
    return [{"dive": d, "base": None, "sources": None} for d in dives]  # base: as the dive was analysed


def _import_folders(
    store: Any, folders: list[str], name: str | None, storage_options: dict[str, Any]
) -> list[dict[str, Any]]:
    """Import each folder (frames already stored are matched, not copied again); a job per dive."""
    from camcal.core.frameset import FrameSetError
    from ingest.importer import import_frame_set, read_frame_set
    from storage import queries
    from storage.files import RemoteFolder

    jobs: list[dict[str, Any]] = []
    for folder in folders:
        try:
            _dir, _manifest, _rows, folder_setup = read_frame_set(RemoteFolder(folder, storage_options))
            target = store.open_dive(name or folder.rstrip("/").rsplit("/", 1)[-1], folder_setup.to_json())
            report = import_frame_set(
                store, folder, dive_id=target.id, analyse=False, storage_options=storage_options
            )
        except FrameSetError as exc:
            raise fail(str(exc)) from None
        except (OSError, ValueError) as exc:
            raise fail(f"{folder}: {exc}") from None
        for file, why in report.problems:
            console.print(labelled("skipped", "yellow", f"{file}: {why}"))
        located = store.call(queries.locate_frames, report.sources)
        by_dive: dict[int, dict[int, str]] = {}
        for key, (fid, dive_id) in located.items():
            by_dive.setdefault(dive_id, {})[fid] = report.sources[key]
        for dive_id, sources in sorted(by_dive.items()):
            d = _dive(store, dive_id)
            if d.id != target.id:
                console.print(f"{len(sources)} frames of {folder} were already stored in dive {d.name}")
            jobs.append({"dive": d, "base": folder_setup, "sources": sources, "folder": folder})
    return jobs


def _dive(store: Any, dive_id: int) -> Any:
    from storage.models import Dive

    with store.read() as s:
        return s.get(Dive, dive_id)


def _start_runner(workers: int, scheduler: str | None) -> Any:
    from ingest.runners import DaskRunner

    try:
        runner = DaskRunner(workers=workers, scheduler=scheduler)
    except (OSError, TimeoutError) as exc:
        where = scheduler or f"a local cluster of {workers} workers"
        raise fail(f"cannot start Dask on {where}: {exc}") from None
    console.print(
        f"dask: {runner.n_workers} workers" + (f" at {scheduler}" if scheduler else " (local cluster)")
    )
    return runner


def _check_calibration(store: Any, ref: str) -> None:
    """Fail before any work if the named calibration is not stored or holds no valid setup."""
    from camcal.core.calibrations import setup_of
    from camcal.core.frameset import FrameSetError
    from ingest.reanalysis import UnknownCalibration, find_calibration

    try:
        setup_of(find_calibration(store, ref))
    except UnknownCalibration as exc:
        raise fail(f"--calibration: {exc}") from None
    except FrameSetError as exc:
        raise fail(f"--calibration {ref}: {exc}") from None


def _start(
    store: Any,
    job: dict[str, Any],
    chosen: Setup | None,
    adjust: Any,
    label: str | None,
    calibration: str | None,
    options: Any,
) -> Any:
    """The job's run, started as the API starts one (`ingest.reanalysis.start_reanalysis`)."""
    from ingest.reanalysis import ReanalysisInputError, start_reanalysis

    what = job.get("folder") or (
        "frames in the span" if options.t_from is not None or options.t_to is not None else "all frames"
    )
    try:
        return start_reanalysis(
            store,
            job["dive"].id,
            actor="cli",
            default_label=f"camcal reanalyze: {what}",
            label=label,
            calibration=calibration,
            setup=chosen or job["base"],
            adjust=adjust,
            what=f": {what}",
        )
    except ReanalysisInputError as exc:
        raise fail(str(exc)) from None


def _run(
    store: Any, job: dict[str, Any], started: Any, options: Any, runner: Any, cancel: threading.Event
) -> dict[str, Any]:
    from ingest.derived import result_row
    from ingest.reanalysis import ReanalysisInterrupted, reanalyse
    from ingest.spans import span_attenuation_by_band, table_rows
    from storage import queries

    d = job["dive"]
    run_id, setup, record = started.run_id, started.setup, started.record
    t0 = time.perf_counter()
    try:
        if cancel.is_set():  # stopped between two dives (a stop within one is marked by reanalyse)
            store.finish_run(run_id, "interrupted")
            raise ReanalysisInterrupted
        n = reanalyse(
            store, d.id, run_id, setup, options, runner=runner, sources=job["sources"], cancel=cancel
        )
    except (ReanalysisInterrupted, KeyboardInterrupt):
        raise fail(
            f"re-analysis of dive {d.name} interrupted (run {run_id}, marked interrupted): run the same "
            "command again to redo it",
            code=130,
        ) from None
    except Exception as exc:
        raise fail(f"re-analysis of dive {d.name} failed (run {run_id}): {exc}", code=1) from None
    elapsed = time.perf_counter() - t0
    rows = [result_row(r) for r in store.call(queries.result_rows, run_id, d.id)]
    table = table_rows(span_attenuation_by_band(rows, setup))  # the whole dive: per depth band
    return {
        "dive": d.name,
        "dive_id": d.id,
        "run_id": run_id,
        "frames": n,
        "ok_frames": sum(1 for r in rows if r.status == "ok"),
        "elapsed_s": round(elapsed, 3),
        "frames_per_s": round(n / elapsed, 2) if elapsed > 0 else None,
        "calibration": setup.to_json(),
        "calibration_record": f"{record['name']}@{record['version']}" if record else None,
        "attenuation": table["rows"],
        "attenuation_by_depth": table["bands"],
    }


def _depth(band: dict[str, Any]) -> str:
    """A depth band's label: ``3420 m`` (the LEM's), a range for a tall one."""
    lo, hi = band["depth_min_m"], band["depth_max_m"]
    if lo is None or hi is None:
        return "depth unknown"
    return f"{(lo + hi) / 2:.0f} m" if hi - lo < 30 else f"{lo:.0f}–{hi:.0f} m"


def _print(summaries: list[dict[str, Any]]) -> None:
    for s in summaries:
        t = Table(
            title=f"dive {s['dive']}: run {s['run_id']}, {s['frames']} frames in {s['elapsed_s']:.1f} s "
            f"({s['frames_per_s'] or 0:.1f} frames/s), {s['ok_frames']} accepted",
            title_justify="left",
        )
        bands = s.get("attenuation_by_depth") or []
        for col in (("depth",) if bands else ()) + (
            "wavelength",
            "λ_att [m]",
            "stat [m]",
            "sys [m]",
            "pairs",
        ):
            t.add_column(col, justify="right")
        rows = [("whole dive", a) for a in s["attenuation"]] + [
            (_depth(b), a) for b in bands for a in b["rows"]
        ]
        for where, a in rows:
            lam = a["lambda_att_m"]
            t.add_row(
                *((where,) if bands else ()),
                f"{a['wavelength_nm']} nm",
                f"{lam:.2f}" if lam is not None else "—",
                f"± {a['stat_err_m']:.2f}" if a["stat_err_m"] is not None else "—",
                f"± {a['sys_err_m']:.2f}" if a["sys_err_m"] is not None else "—",
                str(a["n_pairs"]),
            )
        console.print(t)
        for a in s["attenuation"] if bands else ():  # the whole dive crosses depths: say what that means
            if a.get("note"):
                console.print(f"{a['wavelength_nm']} nm over the whole dive: {a['note']}", soft_wrap=True)
