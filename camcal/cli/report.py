"""``camcal report``: one self-contained HTML report of a stored dive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from camcal.cli.common import DataOption, DbUrlOption, console, fail


def register(app: typer.Typer) -> None:
    app.command("report")(report)


def report(
    dive: Annotated[
        str, typer.Argument(help="Name of the dive (`camcal export` and the dashboard list them).")
    ],
    data: DataOption = None,
    db_url: DbUrlOption = None,
    out: Annotated[
        Path | None, typer.Option(help="The HTML file to write (default: report-DIVE.html).")
    ] = None,
    run: Annotated[
        int | None, typer.Option(help="Analysis run to report (default: the dive's live run).")
    ] = None,
) -> None:
    """Write a dive's report as ONE self-contained HTML file that opens offline (a USB stick, e-mail).

    Timeline, frame quality, linearity, attitude, λ_att over time and depth
    with its table, λ_abs and λ_sca with their Δχ² contours (from the newest
    `camcal fit --dive`; the report says how to make one if there is none),
    the calibration inputs and the software versions. Figures are inline
    PNG; the file loads nothing from anywhere.
    """
    from camcal.cli.data import open_store
    from camcal.core.frameset import FrameSetError
    from camcal.divefit import DiveLookupError
    from camcal.report import write_report

    target = out or Path(f"report-{dive}.html")
    store = open_store(data, db_url)
    try:
        result = write_report(store, dive, target, run)
    except (DiveLookupError, FrameSetError) as exc:
        raise fail(str(exc).splitlines()[0]) from None
    except OSError as exc:  # a full or read-only disk: nothing half-written is left (written whole)
        raise fail(
            f"cannot write the report to {target} ({exc.strerror or exc}): free space or choose "
            "another --out",
            code=1,
        ) from None
    finally:
        store.close()
    size_kb = target.stat().st_size / 1024
    fit = "with" if result.fit else "without"
    console.print(f"wrote {target} ({size_kb:.0f} kB, {fit} a χ² fit)", highlight=False)
