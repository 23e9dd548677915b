"""Importing an SD-card frame set into a dive: idempotent, and it fills the gaps a broken link left.

The folder is read through fsspec: a local folder and an object-store prefix
(``s3://bucket/sets/dive-7``) import the same way.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from analysis import FrameConfig
from camcal.core.frameset import (
    DAMAGED,
    SETUP,
    ManifestRow,
    Setup,
    decode_text,
    parse_manifest,
    parse_setup,
)
from camcal.core.images import FrameReadError, decode_frame
from camcal.core.parallel import process_pool
from camcal.core.utctime import parse_utc_unix_s
from camcal.core.wire.limits import TIME_MIN_UNIX_S
from camcal.core.wire.models import is_id
from camcal.core.wire.sensors import check_columns, check_rows
from ingest.alarms import utc_minute
from ingest.seqtrack import SeqTracker
from ingest.worker import analyse_stored_frame
from storage import queries
from storage.files import RemoteFolder, UnsafePath
from storage.store import FrameRow, SensorBatchRow, Store

#: Frame results an import stores at a time (a stopped import keeps what it analysed).
SAVE_EVERY = 64


@dataclass
class ImportReport:
    """What an import did."""

    folder: Path | str
    dive_id: int
    imported: int = 0
    already_present: int = 0
    #: Of those, frames found by their content: the same image at the same setting (and time, where
    #: both have one) as a stored frame of the camera, under another key (the manifest had no boot
    #: column and changed since the set was imported, or it lists one image twice).
    same_content: int = 0
    sensor_batches: int = 0
    analysed: int = 0
    problems: list[tuple[str, str]] = field(default_factory=list)
    gaps_filled: int = 0
    #: Frames imported without a capture time in the manifest: stamped with the import's clock.
    unstamped: int = 0
    #: λ_att visits of the run after the import (its series made again from all its frames), None
    #: when the import analysed nothing (the series is as it was) or its frames carry no times.
    visits: int | None = None
    #: Every frame of the folder now in the store (imported or already there): (module, boot, seq) -> URL
    #: of its file in the folder.
    sources: dict[tuple[str, str, int], str] = field(default_factory=dict)
    #: The folder's setup.json where it differs from the calibration the dive keeps (and analysed
    #: with): its URL and the values that differ, e.g. ``["cameras.A.distance_m 21.9 -> 21.56"]``.
    setup_ignored: tuple[str, list[str]] | None = None


def _frames_folder(folder: RemoteFolder) -> RemoteFolder:
    """An outbox root holds its frame set in ``frames/``; a plain frame set is the folder itself."""
    return folder.child("frames") if folder.exists("frames/manifest.csv") else folder


def _copy_of_stored(
    stored: Sequence[tuple[int, float, float, float]], row: ManifestRow, captured: float | None
) -> bool:
    """Whether a row's image is a stored frame again: same bytes (the caller's sha256), setting and,
    where both have one, capture time (two lens-capped frames can share their bytes, not their time)."""
    for wl, exp, gain, t in stored:
        if (wl, exp, gain) != (row.wavelength_nm, row.exposure_s, row.gain_db):
            continue
        if captured is None or math.isnan(t) or abs(t - captured) < 1e-3:
            return True
    return False


def _fallback_boot(manifest: bytes) -> str:
    """A stable boot id for a frame set without one: importing it twice gives the same keys."""
    digest = hashlib.sha256(manifest).hexdigest()[:12]
    return f"import-{digest}"


def read_frame_set(folder: RemoteFolder) -> tuple[RemoteFolder, bytes, list[ManifestRow], Setup]:
    """The frame-set folder (``frames/`` of an outbox), its manifest bytes and rows, and its setup.

    Raises `FrameSetError` for a missing or unusable manifest or setup.
    """
    from camcal.core.frameset import MANIFEST, FrameSetError

    frames_dir = _frames_folder(folder)
    try:
        manifest = frames_dir.read_bytes(MANIFEST)
    except FileNotFoundError:
        raise FrameSetError(f"{frames_dir.url}: no {MANIFEST} (not a frame set?)") from None
    except OSError as exc:
        raise FrameSetError(f"{frames_dir.url}: cannot read the manifest ({exc})") from exc
    rows = parse_manifest(decode_text(manifest), f"{frames_dir.url}/{MANIFEST}")
    setup = Setup()
    if frames_dir.exists(SETUP):
        where = f"{frames_dir.url}/{SETUP}"
        try:
            data = json.loads(frames_dir.read_bytes(SETUP))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FrameSetError(f"{where}: not valid JSON ({exc})") from exc
        setup = parse_setup(data, where)
    return frames_dir, manifest, rows, setup


def import_frame_set(
    store: Store,
    folder: Path | str,
    *,
    dive_id: int,
    run_id: int | None = None,
    analyse: bool = True,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    storage_options: dict[str, object] | None = None,
    clock_offsets_s: Mapping[str, float] | None = None,
) -> ImportReport:
    """Store every readable frame of ``folder`` not yet in the store, then analyse the new ones.

    Frames are keyed by (module, boot, seq) exactly as live frames are, so a
    frame that already arrived over the link is skipped, and one the link
    lost is added (and its gap closed). Unreadable files are reported and
    skipped; sensor batches of an outbox (``sensors.jsonl``) come along.
    ``clock_offsets_s``: per module, how far its clock was ahead of true time
    (behind: negative); its frames' and samples' times are corrected by it.
    A frame stamped before 2000 (a module clock never set) is reported, with
    the option that imports it, and not stored at a time that means nothing.

    The frames are analysed as the live ingest analyses them, with the
    dive's calibration (its live run's, else its own setup); a dive that has
    neither takes the frame set's ``setup.json`` as its own. The run's λ_att
    series is then made again from all its frames (`derive_run`): the
    visits the imported frames fill or join.
    """
    from ingest.reanalysis import derive_run, stored_setup

    offsets = clock_offsets_s or {}
    root = RemoteFolder(folder, storage_options)
    # a broken manifest or setup.json stops the import early
    frames_dir, manifest, rows, folder_setup = read_frame_set(root)
    setup = stored_setup(store, dive_id)
    report = ImportReport(folder, dive_id)
    if setup is None:
        store.adopt_dive_setup(dive_id, folder_setup.to_json())
        setup = folder_setup
    elif frames_dir.exists(SETUP) and (changes := setup_changes(setup.to_json(), folder_setup.to_json())):
        report.setup_ignored = (f"{frames_dir.url}/{SETUP}", changes)
    fallback = _fallback_boot(manifest)
    batch: list[FrameRow] = []
    new: list[tuple[int, str, str]] = []
    touched: set[tuple[str, str]] = set()

    def flush() -> None:
        if not batch:
            return
        outcome = store.commit_batch(dive_id, batch)
        report.imported += len(outcome.new_frames)
        report.already_present += len(outcome.duplicate_frames)
        by_key = {(f.module_id, f.boot, f.seq): f for f in batch}
        new.extend((fid, by_key[k].path, by_key[k].module_id) for k, fid in outcome.new_frames.items())
        batch.clear()

    stored: dict[tuple[str, str], set[int]] = {}
    contents: dict[str, dict[str, list[tuple[int, float, float, float]]]] = {}  # per camera, by sha256
    first_row: dict[tuple[str, str, int], int] = {}  # the row of the folder that holds each number
    for i, row in enumerate(rows):
        if progress:
            progress(i, len(rows))
        if row.error:
            report.problems.append((row.file or f"row {i + 1}", row.error))
            continue
        boot = row.boot or fallback
        seq = row.seq if row.seq is not None else i + 1
        if not is_id(row.camera) or not is_id(boot):  # ".." would name a folder above the dive's
            report.problems.append(
                (row.file or f"row {i + 1}", f"camera {row.camera!r} or boot {boot!r} is not a valid id")
            )
            continue
        if (row.camera, boot, seq) in first_row:  # a number is one frame: the first row keeps it
            report.problems.append(
                (
                    row.file or f"row {i + 1}",
                    f"repeats the sequence number {seq} of camera {row.camera} (boot {boot}) of row "
                    f"{first_row[(row.camera, boot, seq)] + 1}: not imported (a card written when a full "
                    "card could leave a failed frame's row; its values may belong to another frame)",
                )
            )
            continue
        first_row[(row.camera, boot, seq)] = i
        if (row.camera, boot) not in stored:
            stored[(row.camera, boot)] = store.call(queries.known_seqs, row.camera, boot)
        if seq in stored[(row.camera, boot)]:  # arrived over the link, or imported before
            report.already_present += 1
            report.sources[(row.camera, boot, seq)] = frames_dir.file_url(row.file)
            continue
        try:
            stamped = parse_utc_unix_s(row.timestamp) if row.timestamp else None
        except ValueError as exc:
            report.problems.append(
                (row.file, f"timestamp {exc}: correct it in the manifest and import again")
            )
            continue
        captured = stamped - offsets.get(row.camera, 0.0) if stamped is not None else time.time()
        if captured < TIME_MIN_UNIX_S:
            report.problems.append((row.file, _unset_clock(row.camera, stamped or 0.0)))
            continue
        try:
            data = frames_dir.read_bytes(row.file)
            frame = decode_frame(data, row.file)
        except FileNotFoundError:
            report.problems.append((row.file, "file not found"))
            continue
        except (OSError, FrameReadError, UnsafePath) as exc:
            report.problems.append((row.file, getattr(exc, "detail", str(exc))))
            continue
        sha = hashlib.sha256(data).hexdigest()
        if row.camera not in contents:
            contents[row.camera] = store.call(queries.frame_contents, dive_id, row.camera)
        when = captured if stamped is not None else None
        if _copy_of_stored(contents[row.camera].get(sha, ()), row, when):
            report.already_present += 1
            report.same_content += 1
            continue
        if stamped is None:
            report.unstamped += 1
        contents[row.camera].setdefault(sha, []).append(
            (row.wavelength_nm, row.exposure_s, row.gain_db, when if when is not None else math.nan)
        )
        encoding = "png" if data.startswith(b"\x89PNG") else "tiff"
        rel = store.files.relative_path(dive_id, row.camera, boot, seq, encoding)
        store.files.write(rel, data)
        batch.append(
            FrameRow(
                module_id=row.camera,
                boot=boot,
                seq=seq,
                captured_unix_s=captured,
                received_unix_s=time.time(),
                wavelength_nm=row.wavelength_nm,
                exposure_s=row.exposure_s,
                gain_db=row.gain_db,
                depth_m=row.depth_m,
                width_px=frame.shape[1],
                height_px=frame.shape[0],
                path=rel,
                size_bytes=len(data),
                sha256=sha,
                schedule_version=row.schedule_version or 0,
                source="import",
            )
        )
        touched.add((row.camera, boot))
        report.sources[(row.camera, boot, seq)] = frames_dir.file_url(row.file)
        if len(batch) >= 64:
            flush()
    flush()
    if progress:
        progress(len(rows), len(rows))
    if root.exists("sensors.jsonl"):
        module = rows[0].camera if rows else None
        batches = []
        skipped: list[str] = []
        for line in decode_text(root.read_bytes("sensors.jsonl")).splitlines():
            try:
                if DAMAGED in line:  # its values cannot be trusted (a failing card)
                    raise ValueError("damaged bytes in this line (not UTF-8: a failing card?)")
                obj = json.loads(line)
                columns = tuple(obj["columns"])
                problem = check_columns(columns)
                if problem:
                    raise ValueError(problem)
                rows_in = obj["rows"]
                shift = offsets.get(module or "", 0.0)
                if shift and "t_unix_s" in columns:  # the module's clock, corrected
                    i_t = columns.index("t_unix_s")
                    rows_in = [_shifted(r, i_t, shift) for r in rows_in]
                samples = check_rows(columns, rows_in, len(rows_in))  # the link's checks
            except (json.JSONDecodeError, KeyError, ValueError, TypeError) as exc:
                skipped.append(str(exc)[:200])
                continue
            if module:
                batches.append(SensorBatchRow(module, obj["boot"], int(obj["seq"]), time.time(), samples))
                touched.add((module, obj["boot"]))
        for why in skipped[:3]:  # (a clock never set spoils every line alike: three say it)
            report.problems.append(("sensors.jsonl", f"a line was skipped: {why}"))
        if len(skipped) > 3:
            report.problems.append(("sensors.jsonl", f"... and {len(skipped) - 3} more lines skipped"))
        if batches:
            out = store.commit_batch(dive_id, [], batches)
            report.sensor_batches = len(out.new_sensor_batches)
    for module, boot in touched:
        seqs = SeqTracker()
        seqs.seed(module, boot, store.call(queries.known_seqs, module, boot))
        report.gaps_filled += len(store.fill_gaps(module, boot, partial(seqs.covers, module, boot)))
    if analyse and run_id is not None:
        # the new frames, and those of this folder an earlier import stored but did not analyse
        # (it was stopped): nothing else analyses them
        todo = new + unanalysed(store, dive_id, run_id, report.sources, {fid for fid, _, _ in new})
        if todo:
            both = (lambda k, n: progress(len(rows) + k, len(rows) + n)) if progress else None
            report.analysed = analyse_frames(store, run_id, todo, workers=workers, setup=setup, progress=both)
            if any(r.timestamp for r in rows):  # frames without capture times make no series over time
                report.visits = derive_run(store, dive_id, run_id, setup)
    return report


def unanalysed(
    store: Store,
    dive_id: int,
    run_id: int,
    keys: Mapping[tuple[str, str, int], object],
    skip: set[int],
) -> list[tuple[int, str, str]]:
    """Frames of ``keys`` (module, boot, seq) stored in the dive without a result in the run."""
    modules = sorted({module for module, _, _ in keys})
    if not modules:
        return []
    pending = store.call(queries.frames_without_result, dive_id, run_id, modules=modules)
    return [
        (f.id, f.path, f.module_id)
        for f in pending
        if f.id not in skip and (f.module_id, f.boot, f.seq) in keys
    ]


def analyse_frames(
    store: Store,
    run_id: int,
    frames: list[tuple[int, str, str]],
    *,
    workers: int = 1,
    setup: Setup | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Analyse stored frames ``(frame_id, path, camera)`` into a run, on ``workers`` processes,
    each with its camera's settings (`Setup.frame_settings`: the linear range, the disk's size)."""
    setup = setup or Setup()
    configs: dict[str, FrameConfig] = {}

    def config(camera: str) -> FrameConfig:
        if camera not in configs:
            configs[camera] = FrameConfig(**setup.frame_settings(camera))
        return configs[camera]

    thumbs = store.files.root / "thumbs"
    saved = done = 0
    rows: list[dict[str, Any]] = []

    def take(fid: int, row: dict[str, Any]) -> None:
        """Keep a result; store them SAVE_EVERY at a time, so that a stopped import keeps its work."""
        nonlocal saved, done
        for k in ("analysis_s", "width_px", "height_px"):
            row.pop(k, None)
        rows.append({**row, "frame_id": fid, "analysed_unix_s": time.time()})
        done += 1
        if progress:
            progress(done, len(frames))
        if len(rows) >= SAVE_EVERY:
            saved += store.save_results(run_id, rows)
            rows.clear()

    try:
        if workers <= 1:
            for fid, path, camera in frames:
                thumb = str(thumbs / f"{fid}.jpg")
                take(fid, analyse_stored_frame(str(store.files.resolve(path)), config(camera), thumb))
        else:
            with process_pool(workers) as pool:
                futures = [
                    (
                        fid,
                        pool.submit(
                            analyse_stored_frame,
                            str(store.files.resolve(path)),
                            config(camera),
                            str(thumbs / f"{fid}.jpg"),
                        ),
                    )
                    for fid, path, camera in frames
                ]
                try:
                    for fid, f in futures:
                        take(fid, f.result())
                except BaseException:  # Ctrl-C: the frames not started are not waited for
                    for _, f in futures:
                        f.cancel()
                    raise
    finally:  # stopped or not, what was analysed is kept
        saved += store.save_results(run_id, rows)
    return saved


def _unset_clock(module: str, stamped_unix_s: float) -> str:
    reads = utc_minute(stamped_unix_s)
    return (
        f"captured at {reads} UTC by module {module}'s clock, which was not set: import again with "
        f"--clock-offset {module}=-SECONDS, how far it was behind (the ship's 'clock' alarm names it)"
    )


def _shifted(row: object, i: int, shift_s: float) -> object:
    """A sensor row with its time corrected by ``shift_s`` (anything else left for the checks)."""
    if not isinstance(row, list) or len(row) <= i or isinstance(row[i], bool):
        return row
    if not isinstance(row[i], int | float):
        return row
    return [*row[:i], row[i] - shift_s, *row[i + 1 :]]


def setup_changes(kept: dict[str, Any], other: dict[str, Any], prefix: str = "") -> list[str]:
    """The values of ``other`` that differ from ``kept``'s, as ``"key.path old -> new"`` lines."""
    out: list[str] = []
    for key in sorted(set(kept) | set(other)):
        a, b, name = kept.get(key), other.get(key), f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += setup_changes(a, b, f"{name}.")
        elif a != b:
            out.append(f"{name} {a} -> {b}")
    return out
