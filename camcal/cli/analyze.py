"""``camcal analyze``: I_center on every frame of a frame set and λ_att per wavelength."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table
from rich.text import Text

from camcal.cli.common import console, fail, labelled, progress_bar, writable_output
from camcal.cli.overrides import (
    DistanceErrOption,
    DistanceOption,
    LinearRangeOption,
    RatioOption,
    overrides_from,
)
from camcal.core.files import write_atomic

if TYPE_CHECKING:
    from camcal.pipeline import FrameSetAnalysis


def register(app: typer.Typer) -> None:
    app.command("analyze")(analyze)


def analyze(
    folder: Annotated[
        Path,
        typer.Argument(
            help="Frame-set folder (manifest.csv, setup.json, images), or one frame file of a frame set."
        ),
    ],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the results as JSON here.")] = None,
    plots: Annotated[Path | None, typer.Option(help="Write figures (PNG) into this folder.")] = None,
    distance: DistanceOption = None,
    distance_err: DistanceErrOption = None,
    ratio: RatioOption = None,
    linear_range: LinearRangeOption = None,
    workers: Annotated[int, typer.Option(help="Worker processes (default: all cores).")] = 0,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Measure I_center on every frame and the attenuation length per wavelength.

    Given one frame file of a frame set, measure that frame alone (its
    manifest row and the set's setup.json say how): I_center and why a frame
    is rejected, without starting worker processes.
    """
    if not folder.exists():
        raise fail(f"{folder}: no such frame-set folder or frame file")
    writable_output(json_out, "--json")
    writable_output(plots, "--plots", folder=True)
    single = folder.is_file()
    from camcal.core.frameset import FrameSetError
    from camcal.pipeline import analyze_rows, load_frame_set, to_json

    overrides = overrides_from(distance, distance_err, ratio, linear_range)
    if single:
        folder, name = folder.parent, folder.name
    try:
        rows, setup = load_frame_set(folder, overrides)
    except FrameSetError as exc:
        raise fail(str(exc)) from None
    cameras, wavelengths = {r.camera for r in rows}, {r.wavelength_nm for r in rows}
    unused = [
        f"--distance {c}=...: the manifest has no camera {c}"
        for c in overrides.distances_m or {}
        if c not in cameras
    ]
    unused += [
        f"--ratio {wl}=...: the manifest has no frame at {wl} nm"
        for wl in overrides.emission_ratios or {}
        if wl not in wavelengths
    ]
    for u in unused:  # an option that names what the set lacks changes nothing: say so
        console.print(labelled("warning:", "yellow", u))
    if single:
        rows = [r for r in rows if Path(r.file).name == name and (folder / r.file).samefile(folder / name)]
        if not rows:
            raise fail(f"{folder / name}: not a frame of the manifest in {folder}")
        workers = 1
    with progress_bar("analysing", quiet=quiet or single) as update:
        result = analyze_rows(folder, rows, setup, workers=workers or None, progress=update)
    if single:
        print_frame(result)
    else:
        print_summary(result)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(json_out, (json.dumps(to_json(result), indent=1) + "\n").encode(), fsync=False)
        console.print(f"wrote {json_out}")
    if plots:
        from camcal.plots import write_plots

        for p in write_plots(result, plots):
            console.print(f"wrote {p}")


def print_frame(an: FrameSetAnalysis) -> None:
    """One frame's measurement, or why it was rejected."""
    from analysis import REASON_HELP

    (row,), (f,) = an.rows, an.frames
    setting = f"{row.wavelength_nm} nm, {row.exposure_s:g} s, {row.gain_db:g} dB"
    what = f"{row.file} (camera {row.camera}, {setting})"
    if not f.ok or f.centroid_px is None:
        console.print(
            Text.assemble(
                f"{what}: ",
                ("rejected", "yellow"),
                f" ({f.reason}: {f.detail or REASON_HELP.get(f.reason or '', '')})",
            ),
            highlight=False,
        )
        return
    x, y = f.centroid_px
    console.print(
        f"{what}: I_center {f.i_center_gray:.2f} ± {f.i_center_err_gray:.2f} gray "
        f"(centre {f.center_gray:.1f}, background {f.background_gray:.2f} gray; "
        f"LEM at ({x:.1f}, {y:.1f}) px, radius {f.radius_px:.1f} px)",
        highlight=False,
    )
    clipped = f.profile.unclipped if f.profile is not None else None
    if clipped is not None:
        console.print(
            f"the camera's dark level sits at 0: its noise ({clipped.sigma_gray:.2f} gray) was clipped there "
            f"({clipped.n_zero_pixels:.0f} dark pixels read 0); the band means were unclipped, by up to "
            f"{clipped.max_shift_gray:.2f} gray (docs/series.md, 'A black level at zero')",
            highlight=False,
        )


def print_summary(an: FrameSetAnalysis) -> None:
    """λ_att per wavelength and the frame counts by reason, as tables."""
    from analysis import REASON_HELP

    table = Table(title="attenuation length λ_att", title_justify="left")
    for col in ("wavelength", "λ_att [m]", "stat [m]", "sys [m]", "pairs", "χ²/ndof"):
        table.add_column(col, justify="right")
    if an.result is not None:
        for wl, res in sorted(an.result.attenuation.items()):
            if res.lambda_att_m is None:
                chi2 = _chi2_text(res.n_pairs, res.chi2_ndof)
                table.add_row(f"{wl} nm", "—", "—", "—", str(res.n_pairs), chi2)
                continue
            table.add_row(
                f"{wl} nm",
                f"{res.lambda_att_m:.2f}",
                f"± {res.stat_err_m:.2f}",
                f"± {res.sys_err_m:.2f}",
                str(res.n_pairs),
                _chi2_text(res.n_pairs, res.chi2_ndof),
            )
    console.print(table)
    if an.problem:
        console.print(labelled("no λ_att:", "yellow", an.problem))
    for w in an.warnings:
        console.print(labelled("warning:", "yellow", w))
    if an.result is not None:
        for wl, why in sorted(an.result.skipped.items()):
            console.print(labelled(f"{wl} nm skipped:", "yellow", why))
    counts = an.counts()
    frames = Table(title=f"frames: {len(an.frames)}", title_justify="left")
    frames.add_column("status")
    frames.add_column("count", justify="right")
    frames.add_column("what it means")
    frames.add_row("accepted", str(counts.get("ok", 0)), "LEM found, in the linear range")
    for reason, n in sorted(counts.items()):
        if reason != "ok":
            frames.add_row(reason, str(n), REASON_HELP.get(reason, ""))
    console.print(frames)


def _chi2_text(n_pairs: int, chi2_ndof: float) -> str:
    """The pairs' agreement; with one pair there is none to measure (no degree of freedom), not 0.00."""
    return f"{chi2_ndof:.2f}" if n_pairs > 1 else "—"
