"""``camcal fit``: λ_abs and λ_sca per wavelength from the radial profiles (the χ² method)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

from camcal.cli.analyze import parse_ratios
from camcal.cli.common import console, err_console, fail, parse_floats, parse_mapping
from camcal.frameset import FrameSetError, write_atomic
from lrm.sim.camera import CameraModel

if TYPE_CHECKING:
    from camcal.fitset import FolderFit

TREX_FOCAL_PX = CameraModel().focal_px


def register(app: typer.Typer) -> None:
    app.command("fit")(fit)


@contextmanager
def stage_progress(quiet: bool) -> Iterator[Callable[[str, int, int], None]]:
    """One progress bar per stage (analysing, templates, fitting), on stderr."""
    if quiet:
        yield lambda stage, done, total: None
        return
    with Progress(
        TextColumn("[bold]{task.description:<10}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err_console,
    ) as prog:
        tasks: dict[str, TaskID] = {}

        def update(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = prog.add_task(stage, total=total)
            prog.update(tasks[stage], completed=done, total=total)

        yield update


def fit(
    folder: Annotated[Path, typer.Argument(help="Frame-set folder (manifest.csv, setup.json, images).")],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the results as JSON here.")] = None,
    plots: Annotated[
        Path | None, typer.Option(help="Write contour and fit figures (PNG) into this folder.")
    ] = None,
    focal_px: Annotated[
        float, typer.Option(help="Camera focal length in pixels (T-REX: 8709, 16° over 2448 px in water).")
    ] = TREX_FOCAL_PX,
    mie_g: Annotated[float, typer.Option(help="Mie <cos theta> of the templates (held fixed).")] = 0.93,
    rayleigh_fraction: Annotated[float, typer.Option(help="Share of scattering that is Rayleigh.")] = 0.17,
    refractive_index: Annotated[
        float, typer.Option(help="Refractive index (recorded with the templates).")
    ] = 1.35,
    sca_nodes: Annotated[
        str, typer.Option(help="Scattering-length nodes of the templates [m], comma-separated.")
    ] = "12,20,33,55,90,150,250",
    photons: Annotated[int, typer.Option(help="Monte Carlo photons per template node.")] = 1_000_000,
    seed: Annotated[int, typer.Option(help="Seed of the templates' Monte Carlo.")] = 0,
    cache_dir: Annotated[
        Path | None,
        typer.Option(help="Template cache (default: $CAMCAL_CACHE_DIR or ~/.cache/camcal/templates)."),
    ] = None,
    min_frames: Annotated[int, typer.Option(help="Accepted frames needed per camera and wavelength.")] = 3,
    psf_sigma: Annotated[float, typer.Option(help="Gaussian PSF width [px] (prior centre).")] = 1.2,
    psf_sigma_err: Annotated[float, typer.Option(help="Prior width of the PSF width [px].")] = 0.3,
    template_errors: Annotated[
        bool,
        typer.Option(
            help="Count the templates' Monte Carlo errors (off for frames simulated from these templates)."
        ),
    ] = True,
    distance: Annotated[
        list[str] | None, typer.Option(help="Override a camera distance: CAM=METRES.")
    ] = None,
    distance_err: Annotated[
        list[str] | None, typer.Option(help="Override a distance error: CAM=METRES.")
    ] = None,
    ratio: Annotated[
        list[str] | None, typer.Option(help="Override I0'/I0: NM=VALUE[:ERR], e.g. 460=1.27:0.04.")
    ] = None,
    workers: Annotated[int, typer.Option(help="Worker processes (default: all cores).")] = 0,
    quiet: Annotated[bool, typer.Option(help="No progress bars.")] = False,
) -> None:
    """Fit absorption and scattering lengths to both cameras' radial profiles, per wavelength.

    Templates (photon transport) are built on first use and cached. Checks
    that 1/λ_abs + 1/λ_sca agrees with the I_center attenuation length.
    """
    nodes = parse_floats(sca_nodes, "--sca-nodes")
    from analysis.chisq import FitConfig, FitInputError
    from camcal.fitplots import write_fit_plots
    from camcal.fitset import FitOptions, fit_folder, to_json
    from camcal.pipeline import Overrides

    try:
        options = FitOptions(
            focal_px=focal_px,
            lambda_sca_nodes_m=tuple(sorted(set(nodes))),
            mie_g=mie_g,
            rayleigh_fraction=rayleigh_fraction,
            refractive_index=refractive_index,
            n_photons=photons,
            seed=seed,
            cache_dir=str(cache_dir) if cache_dir else None,
            min_frames=min_frames,
            workers=workers or None,
            fit=FitConfig(
                psf_sigma_px=psf_sigma, psf_sigma_err_px=psf_sigma_err, template_errors=template_errors
            ),
        )
        overrides = Overrides(
            distances_m=parse_mapping(distance, "--distance") or None,
            distance_errs_m=parse_mapping(distance_err, "--distance-err") or None,
            emission_ratios=parse_ratios(ratio) or None,
        )
        with stage_progress(quiet) as update:
            result = fit_folder(folder, options, overrides, progress=update)
    except (FrameSetError, FitInputError, ValueError) as exc:
        raise fail(str(exc).splitlines()[0]) from None
    print_fits(result)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(json_out, (json.dumps(to_json(result), indent=1) + "\n").encode(), fsync=False)
        console.print(f"wrote {json_out}")
    if plots:
        for p in write_fit_plots(result, plots):
            console.print(f"wrote {p}")


def print_fits(result: FolderFit) -> None:
    """λ_abs, λ_sca and the λ_att check per wavelength, as a table; skipped wavelengths below."""
    table = Table(title="absorption and scattering lengths (χ² fit)", title_justify="left")
    for col in (
        "wavelength",
        "λ_abs [m]",
        "λ_sca [m]",
        "λ_att fit [m]",
        "λ_att I_center [m]",
        "check",
        "χ²/ndof",
    ):
        table.add_column(col, justify="right")
    for wl, f in sorted(result.fits.items()):
        chk = result.checks[wl]
        if chk.lambda_att_icenter_m is None:
            ic, verdict = "—", "—"
        else:
            ic = f"{chk.lambda_att_icenter_m:.2f} ± {chk.lambda_att_icenter_err_m:.2f}"
            verdict = f"{'[green]agrees' if chk.agrees else '[red]differs'}[/] ({chk.z:+.1f}σ)"
        edge = " [yellow](grid edge)[/]" if f.at_edge else ""
        table.add_row(
            str(wl),
            f"{f.lambda_abs_m:.2f} ± {f.lambda_abs_err_m:.2f}",
            f"{f.lambda_sca_m:.2f} ± {f.lambda_sca_err_m:.2f} ± {f.lambda_sca_sys_err_m:.2f}{edge}",
            f"{f.lambda_att_m:.2f} ± {f.lambda_att_err_m:.2f}",
            ic,
            verdict,
            f"{f.chi2:.0f}/{f.ndof}",
        )
    console.print(table)
    console.print(
        "errors: statistical (Δχ² = 1); λ_sca's second error is the templates' systematic", style="dim"
    )
    for wl, why in sorted(result.skipped.items()):
        console.print(f"[yellow]{wl} nm skipped:[/] {why}")
