"""``camcal import`` and ``camcal export``: SD cards into the store, dives out of it."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from camcal.cli.common import DataOption, DbUrlOption, console, fail, parse_mapping, progress_bar


def register(app: typer.Typer) -> None:
    app.command("import")(import_cmd)
    app.command("export")(export_cmd)


def store_location(data: Path | None, db_url: str | None) -> tuple[Path, str | None]:
    """The data folder and database URL a command uses: its options, else the typed settings
    (``CAMCAL_DATA_DIR``, ``CAMCAL_DATABASE_URL``, the config file), else the defaults."""
    from camcal.cli.config import settings_or_fail

    settings = settings_or_fail(data_dir=data, database_url=db_url)
    return settings.data_dir, settings.database_url


def open_store(data: Path | None, db_url: str | None, *, create: bool = False):
    """The store ``--data``/``--db-url`` (or the settings) name; a missing one is one line, not a new one."""
    data, db_url = store_location(data, db_url)
    from storage.store import Store

    if not create and db_url is None and not (data / "camcal.db").exists():
        raise fail(
            f"{data}: no camcal store here (run `camcal ingest --data {data}`, "
            "or name it with --data/--db-url or CAMCAL_DATA_DIR/CAMCAL_DATABASE_URL)"
        )
    try:
        return Store.open(data, db_url)
    except ImportError:
        raise  # a driver of an extra not installed (psycopg): `camcal.cli.main` names the extra
    except Exception as exc:
        raise fail(f"cannot open the store: {exc}") from None


def pick_dive(store, name: str | None, *, create_as: str | None = None):
    from storage import queries

    if name:
        dive = store.call(queries.dive_by_name, name)
        if dive is None:
            if create_as is not None:
                return store.create_dive(name)
            raise fail(f"no dive named {name!r}")
        return dive
    dive = store.current_dive(create=False)
    if dive is None:
        from sqlalchemy import select

        from storage.models import Dive

        with store.read() as s:
            dive = s.scalars(select(Dive).order_by(Dive.id.desc())).first()
    if dive is None:
        if create_as is not None:
            return store.create_dive(create_as)
        raise fail("the store holds no dive yet")
    return dive


def import_cmd(
    folder: Annotated[Path, typer.Argument(help="An SD-card outbox or any frame set.")],
    data: DataOption = None,
    db_url: DbUrlOption = None,
    dive: Annotated[str | None, typer.Option(help="Dive to import into (default: the latest).")] = None,
    workers: Annotated[int, typer.Option(help="Analysis processes.")] = 2,
    analyse: Annotated[bool, typer.Option(help="Analyse the imported frames.")] = True,
    clock_offset: Annotated[
        list[str] | None,
        typer.Option(
            help="A module clock that was off: CAM=SECONDS it was ahead of true time (behind: negative; "
            "the ship's 'clock' alarm names it). Its frames' and samples' times are corrected."
        ),
    ] = None,
) -> None:
    """Load an SD-card frame set into a dive: frames already stored are skipped, gaps are filled."""
    from camcal.core import __version__
    from camcal.core.frameset import FrameSetError
    from ingest.importer import import_frame_set

    offsets = parse_mapping(clock_offset, "--clock-offset")
    store = open_store(data, db_url, create=True)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # `kill`, systemd: as Ctrl-C
    try:
        d = pick_dive(store, dive, create_as=dive or folder.name)
        run = store.analysis_run(d.id, "live", software_version=__version__)
        with progress_bar("importing, analysing") as update:
            report = import_frame_set(
                store,
                folder,
                dive_id=d.id,
                run_id=run.id,
                analyse=analyse,
                workers=workers,
                progress=update,
                clock_offsets_s=offsets,
            )
    except FrameSetError as exc:
        raise fail(str(exc)) from None
    except KeyboardInterrupt:
        raise fail(
            "stopped: the frames stored so far are kept, and what was analysed; the same import again "
            "takes the rest (frames already stored are skipped, those without a result analysed)",
            code=130,
        ) from None
    except Exception as exc:
        from ingest.faults import ships_fault
        from storage.db import error_line

        if not ships_fault(exc):
            raise
        raise fail(  # nothing half-stored is counted: the same import again takes what is missing
            f"cannot store into {store.files.root} ({error_line(exc)}): free space (or make the data folder "
            "writable) and run the same import again; the frames already imported are skipped",
            code=1,
        ) from None
    finally:
        store.close()
    console.print(
        f"dive {d.name}: {report.imported} frames imported, {report.already_present} already present, "
        f"{report.sensor_batches} sensor batches, {report.analysed} analysed, "
        f"{report.gaps_filled} gaps closed"
        + (f", {report.visits} λ_att visits" if report.visits is not None else ""),
        soft_wrap=True,
    )
    if report.same_content:
        console.print(
            f"{report.same_content} of those already present by their content: the same image, setting "
            "(and time) as a frame the dive holds under another number (a manifest without a boot "
            "column that changed since, or a row listed twice): not stored again.",
            soft_wrap=True,
        )
    if report.unstamped:
        console.print(
            f"{report.unstamped} frames had no capture time (the manifest's timestamp column): "
            "stamped with this import's clock. The dive's times, and its λ_att series over time, mean "
            "nothing for them (with no time at all, no series is made: `camcal analyze` gives the set's "
            "λ_att); add the times to the manifest to place them.",
            style="yellow",
            soft_wrap=True,
        )
    if report.setup_ignored:
        where, changes = report.setup_ignored
        shown = "; ".join(changes[:4]) + (f" and {len(changes) - 4} more" if len(changes) > 4 else "")
        console.print(
            f"dive {d.name} keeps the calibration it was analysed with: {where} differs ({shown}) "
            f"and was not used. To analyse the dive with it: camcal reanalyze --dive {d.name} --setup "
            f"{where}" + (f" --data {data}" if data else ""),
            style="yellow",
            soft_wrap=True,
        )
    if report.problems:
        t = Table(title=f"{len(report.problems)} not imported", title_justify="left")
        t.add_column("file")
        t.add_column("why")
        for name, why in report.problems:
            t.add_row(name, why)
        console.print(t)


def export_cmd(
    out: Annotated[Path, typer.Option(help="Folder to write the tables into.")] = Path("export"),
    data: DataOption = None,
    db_url: DbUrlOption = None,
    dive: Annotated[str | None, typer.Option(help="Dive to export (default: the latest).")] = None,
    fmt: Annotated[str, typer.Option("--format", help="csv, parquet, or csv,parquet.")] = "csv,parquet",
) -> None:
    """Write a dive's tables (frames with results, sensors, attitude, λ_att, alarms...) to CSV and Parquet."""
    from ingest.dive_export import export_dive_with_results

    store = open_store(data, db_url)
    try:
        d = pick_dive(store, dive)
        run = store.analysis_run(d.id, "live", create=False)
        formats = tuple(f.strip() for f in fmt.split(",") if f.strip())
        if not formats:
            raise ValueError("--format: name csv, parquet or both (csv,parquet)")
        files = export_dive_with_results(store, d.id, out, formats, run.id if run else None)
    except ValueError as exc:
        raise fail(str(exc)) from None
    except OSError as exc:  # a full or read-only disk: the tables written so far are whole
        raise fail(
            f"cannot write the export into {out} ({exc.strerror or exc}): free space or choose another "
            "--out (no half-written table is left)",
            code=1,
        ) from None
    finally:
        store.close()
    console.print(f"dive {d.name}: wrote {len(files)} files to {out}", soft_wrap=True)
