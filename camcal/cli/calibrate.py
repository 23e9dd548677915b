"""``camcal calibrate``: the lab calibrations of the camera system, one subcommand per experiment."""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from camcal.cli.common import console, fail, labelled, progress, yes_no
from camcal.cli.defaults import DEEP_SEA_TEMPERATURE_C, LEM_DIAMETER_M
from camcal.core.files import write_atomic

if TYPE_CHECKING:
    from types import ModuleType

    from camcal.calibrate.common import FrameOutcome

calibrate_app = typer.Typer(
    help="Lab calibrations of the camera system: one subcommand per experiment, each on a frame set.",
    no_args_is_help=True,
)


def _plots() -> ModuleType:
    from camcal.calibrate import plots

    return plots


def _cal() -> ModuleType:
    """The calibrations (`camcal.calibrate`), imported when a command runs, not for ``--help``."""
    import camcal.calibrate

    return camcal.calibrate


def register(app: typer.Typer) -> None:
    app.add_typer(calibrate_app, name="calibrate")


FolderArg = Annotated[Path, typer.Argument(help="Frame-set folder (manifest.csv, setup.json, images).")]
JsonOpt = Annotated[Path | None, typer.Option("--json", help="Write the result (docs/calibration.md) here.")]
PlotsOpt = Annotated[Path | None, typer.Option(help="Write the figures (PNG) into this folder.")]
CameraOpt = Annotated[str | None, typer.Option(help="Camera id to use when the set holds several.")]
WorkersOpt = Annotated[int, typer.Option(help="Worker processes (default: all cores).")]
QuietOpt = Annotated[bool, typer.Option(help="No progress bar.")]
DistanceErrOpt = Annotated[
    float | None, typer.Option(help="Distance reading error [m] for every frame (default: the manifest's).")
]
#: Options that change where results go, not what they are: left out of the recorded command.
_OUTPUT_ONLY = {"json_out", "plots", "quiet", "workers"}


def _command_line(ctx: typer.Context) -> str:
    """The command as a calibration record should remember it: the options that shape the result."""
    parts = ["camcal", *ctx.command_path.split()[1:]]
    for param in ctx.command.params:
        val = ctx.params.get(param.name or "")
        if param.name in _OUTPUT_ONLY or val is None:
            continue
        if param.param_type_name == "argument":
            parts.append(str(val))
        elif val != param.default:
            parts += [param.opts[0], str(val)]
    return shlex.join(parts)


@contextmanager
def _lazy_progress(label: str, quiet: bool) -> Iterator[Callable[[int, int], None]]:
    """A transient progress bar on stderr that appears with the first frame read.

    Inputs are checked before any frame is read, so a command stopped by a
    bad frame set prints its one error line and nothing else.
    """
    if quiet:
        yield lambda done, total: None
        return
    with ExitStack() as stack:
        state: dict[str, Any] = {}

        def update(done: int, total: int) -> None:
            if "bar" not in state:
                bar = stack.enter_context(progress(transient=True))
                state["bar"], state["task"] = bar, bar.add_task(label, total=total)
            state["bar"].update(state["task"], completed=done, total=total)

        yield update


def _run(label: str, quiet: bool, func: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Run a calibration with a progress bar; unusable inputs end the command with one line."""
    from camcal.core.frameset import FrameSetError

    try:
        with _lazy_progress(label, quiet) as update:
            return func(*args, progress=update, **kwargs)
    except (FrameSetError, _cal().CalibrationError) as exc:
        raise fail(str(exc)) from None


def _outputs(
    doc: dict[str, Any], json_out: Path | None, plots: Path | None, plot: Callable[[Path], list[Path]]
) -> None:
    for w in doc["warnings"]:
        console.print(labelled("warning:", "yellow", w))
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(json_out, (json.dumps(doc, indent=1) + "\n").encode(), fsync=False)
        console.print(f"wrote {json_out}")
    if plots:
        for p in plot(plots):
            console.print(f"wrote {p}")


def _pm(val: float, err: float, fmt: str) -> str:
    """``value ± error`` in one format; an infinite value (no decay measured) shows as such."""
    return f"{val:{fmt}} ± {err:{fmt}}"


def _table(title: str, columns: list[str]) -> Table:
    t = Table(title=title, title_justify="left")
    for i, col in enumerate(columns):
        t.add_column(col, justify="left" if i == 0 else "right")
    return t


def _frames_table(frames: list[FrameOutcome]) -> None:
    from analysis import REASON_HELP
    from camcal.calibrate.common import reason_counts

    counts = reason_counts(frames)
    t = _table(f"frames: {len(frames)}", ["status", "count", "what it means"])
    t.add_row("accepted", str(counts.pop("ok", 0)), "measured")
    for reason, n in sorted(counts.items()):
        t.add_row(reason, str(n), REASON_HELP.get(reason, ""))
    console.print(t)


@calibrate_app.command("linearity")
def linearity(
    ctx: typer.Context,
    folder: FolderArg,
    json_out: JsonOpt = None,
    plots: PlotsOpt = None,
    camera: CameraOpt = None,
    tolerance: Annotated[
        float, typer.Option(help="Relative deviation from the line that ends the linear range.")
    ] = 0.01,
    workers: WorkersOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """Linear response from darkroom sweeps (1-350 ms at one gain; gains at one exposure)."""
    cal = _run(
        "reading",
        quiet,
        _cal().run_linearity,
        folder,
        camera=camera,
        tolerance=tolerance,
        workers=workers or None,
    )
    t = _table(
        f"linear response, camera {cal.selection.camera}",
        [
            "wavelength / sweep",
            "slope",
            "dark level [gray]",
            "R²",
            "leaves linearity [gray]",
            "linear range",
            "points",
        ],
    )
    for (wl, sweep), c in sorted(cal.curves.items()):
        unit = "gray/s" if sweep == "exposure" else "gray/gain"
        f = c.fit
        t.add_row(
            f"{wl} nm {sweep} @ {c.fixed:g} {'dB' if sweep == 'exposure' else 's'}",
            f"{f.slope:.4g} ± {f.slope_err:.2g} {unit}",
            f"{f.intercept:.2f} ± {f.intercept_err:.2f}",
            f"{f.r2:.5f}",
            _pm(c.departure_gray, c.departure_err_gray, ".1f")
            if c.departure_gray is not None
            else "not reached",
            f"{c.linear_range_gray[0]:.1f} – {c.linear_range_gray[1]:.1f}",
            f"{sum(c.linear)} / {len(c.x)}",
        )
    console.print(t)
    lo, hi = cal.linear_range_gray
    console.print(f"recommended linear range: {lo:.1f} – {hi:.1f} gray (setup.json linear_range)")
    _frames_table(cal.frames)
    doc = _cal().linearity_document(cal, _command_line(ctx))
    _outputs(doc, json_out, plots, lambda out: _plots().plot_linearity(cal, out))


@calibrate_app.command("emission-ratio")
def emission_ratio(
    ctx: typer.Context,
    folder: FolderArg,
    json_out: JsonOpt = None,
    plots: PlotsOpt = None,
    camera: CameraOpt = None,
    temperature_tolerance: Annotated[
        float, typer.Option(help="Readings closer than this [°C] belong to one temperature run.")
    ] = 2.0,
    at_temperature: Annotated[
        float, typer.Option(help="Give I0'/I0 at this temperature [°C] (default: the deep sea).")
    ] = DEEP_SEA_TEMPERATURE_C,
    workers: WorkersOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """I0'/I0 per wavelength from the LEM's two hemispheres, and its change with temperature."""
    cal = _run(
        "reading",
        quiet,
        _cal().run_emission_ratio,
        folder,
        camera=camera,
        temperature_tolerance_c=temperature_tolerance,
        temperature_c=at_temperature,
        workers=workers or None,
    )
    t = _table(
        f"emission ratio I0'/I0, camera {cal.selection.camera}",
        [
            "wavelength",
            "per temperature run",
            f"at {at_temperature:g} °C",
            "change warm/cold",
            "brightness change",
        ],
    )
    for wl, r in sorted(cal.results.items()):
        runs = "\n".join(
            f"{run.ratio:.4f} ± {run.ratio_err:.4f}"
            + (f" @ {run.temperature_c:.1f} °C" if run.temperature_c is not None else "")
            for run in r.runs
        )
        e = r.temperature_effect
        t.add_row(
            f"{wl} nm",
            runs,
            f"{r.ratio:.4f} ± {r.ratio_err:.4f}",
            f"{100 * e.ratio_change:+.2f} ± {100 * e.ratio_change_err:.2f} %" if e else "—",
            f"{100 * e.brightness_change:+.2f} ± {100 * e.brightness_change_err:.2f} %" if e else "—",
        )
    console.print(t)
    _frames_table(cal.frames)
    doc = _cal().emission_document(cal, _command_line(ctx))
    _outputs(doc, json_out, plots, lambda out: _plots().plot_emission(cal, out))


@calibrate_app.command("air-scan")
def air_scan(
    ctx: typer.Context,
    folder: FolderArg,
    json_out: JsonOpt = None,
    plots: PlotsOpt = None,
    camera: CameraOpt = None,
    source_diameter: Annotated[
        float, typer.Option(help="Diameter of the source sphere [m].")
    ] = LEM_DIAMETER_M,
    distance_err: DistanceErrOpt = None,
    workers: WorkersOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """Long-distance test in air: constant centre gray, total gray ∝ 1/L², radius ∝ 1/L (Hough)."""
    cal = _run(
        "reading",
        quiet,
        _cal().run_air_scan,
        folder,
        camera=camera,
        source_diameter_m=source_diameter,
        distance_err_m=distance_err,
        workers=workers or None,
    )
    t = _table(
        f"distance scan in air, camera {cal.selection.camera}",
        [
            "wavelength",
            "distances",
            "centre mu [1/km]",
            "centre change over scan",
            "total ∝ L^-n: n",
            "focal [px]",
        ],
    )
    for wl, r in sorted(cal.results.items()):
        c = r.centre
        d = [p.distance_m for p in c.points]
        span = max(d) - min(d)
        t.add_row(
            f"{wl} nm",
            f"{len(d)}: {min(d):g} – {max(d):g} m",
            f"{1e3 * c.mu_per_m:.3f} ± {1e3 * c.mu_err_per_m:.3f}",
            f"{-100 * c.mu_per_m * span:+.2f} ± {100 * c.mu_err_per_m * span:.2f} %",
            _pm(r.total.exponent, r.total.exponent_err, ".3f") if r.total else "—",
            _pm(r.pinhole.focal_px, r.pinhole.focal_err_px, ".1f") if r.pinhole else "—",
        )
    console.print(t)
    _frames_table(cal.frames)
    doc = _cal().air_scan_document(cal, _command_line(ctx))
    _outputs(doc, json_out, plots, lambda out: _plots().plot_air_scan(cal, out))


@calibrate_app.command("tank-scan")
def tank_scan(
    ctx: typer.Context,
    folder: FolderArg,
    json_out: JsonOpt = None,
    plots: PlotsOpt = None,
    camera: CameraOpt = None,
    distance_err: DistanceErrOpt = None,
    workers: WorkersOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """Water tank: λ_att from the exponential decay of the centre gray, against the same scan in air."""
    cal = _run(
        "reading",
        quiet,
        _cal().run_tank_scan,
        folder,
        camera=camera,
        distance_err_m=distance_err,
        workers=workers or None,
    )
    t = _table(
        f"distance scan in the tank, camera {cal.selection.camera}",
        ["wavelength", "λ_att water [m]", "mu water [1/m]", "mu air [1/m]", "λ_att rel. to air [m]"],
    )
    for wl, r in sorted(cal.results.items()):
        w = r.water
        t.add_row(
            f"{wl} nm",
            _pm(w.lambda_att_m, w.lambda_att_err_m, ".3f"),
            _pm(w.mu_per_m, w.mu_err_per_m, ".4f"),
            _pm(r.air.mu_per_m, r.air.mu_err_per_m, ".4f") if r.air else "no air scan",
            _pm(r.relative.lambda_att_m, r.relative.lambda_att_err_m, ".3f") if r.relative else "—",
        )
    console.print(t)
    _frames_table(cal.frames)
    doc = _cal().tank_scan_document(cal, _command_line(ctx))
    _outputs(doc, json_out, plots, lambda out: _plots().plot_tank_scan(cal, out))


@calibrate_app.command("psf")
def psf(
    ctx: typer.Context,
    folder: FolderArg,
    json_out: JsonOpt = None,
    plots: PlotsOpt = None,
    camera: CameraOpt = None,
    window: Annotated[int, typer.Option(help="Side of the fit window around the source [px], odd.")] = 17,
    max_sigma: Annotated[
        float | None, typer.Option(help="Focus criterion: the PSF sigma must not exceed this [px].")
    ] = None,
    workers: WorkersOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """Focus check: the PSF width from frames of a point-like source."""
    cal = _run(
        "fitting",
        quiet,
        _cal().run_psf,
        folder,
        camera=camera,
        window_px=window,
        max_sigma_px=max_sigma,
        workers=workers or None,
    )
    t = _table(
        f"point spread function, camera {cal.selection.camera}",
        ["wavelength", "σ [px]", "σ_x [px]", "σ_y [px]", "FWHM [px]", "frames", "in focus"],
    )
    for wl, r in sorted(cal.results.items()):
        focus = _cal().psf.in_focus(cal, wl)
        t.add_row(
            f"{wl} nm",
            f"{r.sigma.mean:.3f} ± {r.sigma.err:.3f}",
            f"{r.sigma_x.mean:.3f} ± {r.sigma_x.err:.3f}",
            f"{r.sigma_y.mean:.3f} ± {r.sigma_y.err:.3f}",
            f"{r.fwhm_px:.2f} ± {r.fwhm_err_px:.2f}",
            str(r.sigma.n),
            "—" if focus is None else yes_no(focus),
        )
    console.print(t)
    _frames_table(cal.frames)
    doc = _cal().psf_document(cal, _command_line(ctx))
    _outputs(doc, json_out, plots, lambda out: _plots().plot_psf(cal, out))
