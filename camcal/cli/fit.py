"""``camcal fit``: λ_abs and λ_sca per wavelength from the radial profiles (the χ² method)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from camcal.cli.common import DataOption, DbUrlOption, console, err_console, fail, labelled, parse_floats
from camcal.cli.overrides import DistanceErrOption, DistanceOption, RatioOption, overrides_from
from camcal.core.files import write_atomic

if TYPE_CHECKING:
    from analysis.chisq import ChiSquareFit, Estimate
    from camcal.fitset import FitOptions, FolderFit
    from camcal.pipeline import Overrides


def register(app: typer.Typer) -> None:
    app.command("fit")(fit)


@contextmanager
def stage_progress(quiet: bool) -> Iterator[Callable[[str, int, int], None]]:
    """One progress bar per stage (analysing, templates, fitting), on stderr."""
    if quiet:
        yield lambda stage, done, total: None
        return
    with Progress(
        TextColumn("{task.description:<10}", style="bold", markup=False),
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
    folder: Annotated[
        Path | None, typer.Argument(help="Frame-set folder (manifest.csv, setup.json, images).")
    ] = None,
    dive: Annotated[
        str | None, typer.Option(help="Fit a stored dive instead of a folder (its frames in --data).")
    ] = None,
    data: DataOption = None,
    db_url: DbUrlOption = None,
    run: Annotated[
        int | None, typer.Option(help="Analysis run whose calibration inputs to use (default: the live one).")
    ] = None,
    calibration: Annotated[
        str | None, typer.Option(help="Use this calibration record instead: ID, NAME or NAME@VERSION.")
    ] = None,
    depth_min: Annotated[
        float | None, typer.Option(help="Frames at or below this depth [m] (default: deepest - 50 m).")
    ] = None,
    depth_max: Annotated[float | None, typer.Option(help="Frames at or above this depth [m].")] = None,
    store_result: Annotated[
        bool, typer.Option("--store/--no-store", help="Keep a dive's fit in the store (for the report).")
    ] = True,
    wavelength: Annotated[
        list[int] | None, typer.Option(help="Fit only this wavelength [nm] (repeatable).")
    ] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the results as JSON here.")] = None,
    plots: Annotated[
        Path | None, typer.Option(help="Write contour and fit figures (PNG) into this folder.")
    ] = None,
    focal_px: Annotated[
        float | None,
        typer.Option(
            help="Camera focal length in pixels (default: the setup's focal_px; T-REX: 8709, 16° over "
            "2448 px in water)."
        ),
    ] = None,
    mie_g: Annotated[
        float, typer.Option(help="Mie <cos theta>: the phase map's start, or its value with --fix-phase.")
    ] = 0.93,
    rayleigh_fraction: Annotated[
        float, typer.Option(help="Share of scattering that is Rayleigh (start, or value with --fix-phase).")
    ] = 0.17,
    templates: Annotated[
        str,
        typer.Option(
            help="smooth: exact first order + small-angle orders, smooth in all four optical parameters "
            "(measures the phase function); monte-carlo: the Monte Carlo grid of one phase function."
        ),
    ] = "smooth",
    phase: Annotated[
        bool,
        typer.Option(
            "--phase/--fix-phase",
            help="Measure Mie <cos theta> and the Rayleigh share from the halo (smooth templates), or hold "
            "them at --mie-g / --rayleigh-fraction (then the budget varies them over their priors).",
        ),
    ] = True,
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
    systematics: Annotated[
        bool,
        typer.Option(
            help="Fit ⟨cos θ⟩ and the Rayleigh share with their priors, vary the LEM emission shape, and "
            "report the shifts as the systematic budget (builds alternative templates once)."
        ),
    ] = True,
    sys_photon_factor: Annotated[
        float,
        typer.Option(
            help="Photons per node of the budget's phase-function templates, as a multiple of --photons "
            "(the data tell ⟨cos θ⟩ apart by halo shapes finer than the fit's own templates' noise)."
        ),
    ] = 4.0,
    template_errors: Annotated[
        bool,
        typer.Option(
            help="Count the templates' Monte Carlo errors (off for frames simulated from these templates)."
        ),
    ] = True,
    joint_phase: Annotated[
        bool,
        typer.Option(
            "--joint-phase/--phase-per-wavelength",
            help="Mie <cos theta> shared by the wavelengths (each keeps its Rayleigh share), or measured "
            "per wavelength.",
        ),
    ] = True,
    distance: DistanceOption = None,
    distance_err: DistanceErrOption = None,
    ratio: RatioOption = None,
    workers: Annotated[int, typer.Option(help="Worker processes (default: all cores).")] = 0,
    quiet: Annotated[bool, typer.Option(help="No progress bars.")] = False,
) -> None:
    """Fit absorption and scattering lengths to both cameras' radial profiles, per wavelength.

    Of a frame-set FOLDER, or of a stored dive (--dive NAME --data DIR: by
    default the station's frames, frames within 50 m of the deepest, with
    the live run's calibration inputs; the fit is kept in the store for
    `camcal report`). Templates (photon transport) are built on first use
    and cached. Checks that 1/λ_abs + 1/λ_sca agrees with the I_center
    attenuation length.
    """
    if (folder is None) == (dive is None):
        raise fail("give a frame-set FOLDER or --dive NAME (one of them)")
    nodes = parse_floats(sca_nodes, "--sca-nodes")
    from analysis.chisq import FitConfig, FitInputError
    from analysis.chisq.systematics import SystematicsConfig
    from camcal.core.frameset import FrameSetError
    from camcal.fitdoc import to_json
    from camcal.fitset import FitOptions, fit_folder

    try:
        options = FitOptions(
            focal_px=focal_px,
            lambda_sca_nodes_m=tuple(sorted(set(nodes))),
            mie_g=mie_g,
            rayleigh_fraction=rayleigh_fraction,
            templates=templates,
            float_phase=phase and templates == "smooth",
            joint_phase=joint_phase,
            refractive_index=refractive_index,
            n_photons=photons,
            seed=seed,
            cache_dir=str(cache_dir) if cache_dir else None,
            min_frames=min_frames,
            workers=workers or None,
            wavelengths_nm=tuple(sorted(set(wavelength))) if wavelength else None,
            fit=FitConfig(
                psf_sigma_px=psf_sigma, psf_sigma_err_px=psf_sigma_err, template_errors=template_errors
            ),
            systematics=SystematicsConfig(phase_photon_factor=sys_photon_factor) if systematics else None,
        )
        overrides = overrides_from(distance, distance_err, ratio)
        if dive is not None:
            doc, result = fit_stored_dive(
                dive,
                data,
                db_url,
                run,
                calibration,
                depth_min,
                depth_max,
                options,
                overrides,
                quiet,
                store_result,
            )
        else:
            assert folder is not None
            with stage_progress(quiet) as update:
                result = fit_folder(folder, options, overrides, progress=update)
            doc = None
    except (FrameSetError, FitInputError, ValueError, LookupError) as exc:
        raise fail(str(exc).splitlines()[0]) from None
    print_fits(result)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(doc if doc is not None else to_json(result), indent=1) + "\n"
        write_atomic(json_out, text.encode(), fsync=False)
        console.print(f"wrote {json_out}")
    if plots:
        from camcal.fitplots import write_fit_plots

        for p in write_fit_plots(result, plots):
            console.print(f"wrote {p}")
    if not result.has_result:
        raise fail("no wavelength gave a result: every length is unconstrained (see the table above)", 1)


def fit_stored_dive(
    dive: str,
    data: Path | None,
    db_url: str | None,
    run: int | None,
    calibration: str | None,
    depth_min: float | None,
    depth_max: float | None,
    options: FitOptions,
    overrides: Overrides,
    quiet: bool,
    keep: bool,
) -> tuple[dict[str, Any], FolderFit]:
    """Fit a dive of the store over a span; keep the result there unless told not to."""
    from camcal.cli.data import open_store
    from camcal.divefit import dive_fit_json, dive_inputs, fit_dive, store_dive_fit
    from ingest.spans import Span

    store = open_store(data, db_url)
    try:
        inputs = dive_inputs(
            store,
            dive,
            run_id=run,
            calibration=calibration,
            span=Span(depth_min_m=depth_min, depth_max_m=depth_max),
            overrides=overrides,
        )
        console.print(
            f"dive {dive}: {len(inputs.rows)} frames of run {inputs.run['id']} ({inputs.run['kind']}) "
            f"at depths >= {inputs.span['depth_min_m']:.0f} m",
            highlight=False,
        )
        with stage_progress(quiet) as update:
            result = fit_dive(inputs, options, progress=update)
        doc = dive_fit_json(result)
        if keep:
            fit_id = store_dive_fit(store, result, doc)
            console.print(f"kept as fit {fit_id} of dive {dive} (camcal report {dive} shows it)")
    finally:
        store.close()
    return doc, result.fit


def print_fits(result: FolderFit) -> None:
    """Values or limits per wavelength, the λ_att check, the budget, and what was flagged or skipped."""
    from analysis.chisq.quality import fit_quality

    table = Table(title="absorption and scattering lengths (χ² fit)", title_justify="left")
    for col in (
        "wavelength",
        "λ_abs [m]",
        "λ_sca [m]",
        "λ_att fit [m]",
        "λ_att I_center [m]",
        "check",
        "phase function",
        "χ²/ndof",
    ):
        table.add_column(col, justify="right")
    quality = {wl: fit_quality(f) for wl, f in result.fits.items()}
    for wl, f in sorted(result.fits.items()):
        chk = result.checks[wl]
        verdict: str | Text = "—"
        if chk.lambda_att_icenter_m is None:
            ic = "—"
        else:
            ic = f"{chk.lambda_att_icenter_m:.2f} ± {chk.lambda_att_icenter_err_m:.2f}"
            colour = "green" if chk.agrees else ("bold red" if chk.flagged else "yellow")
            word = "agrees" if chk.agrees else ("FLAGGED" if chk.flagged else "differs")
            verdict = Text.assemble((word, colour), f" ({chk.z:+.1f}σ)")
        if chk.nuisances_flagged:  # a calibration pulled beyond 3σ: said below the table
            flag = Text("calibration FLAGGED", style="bold red")
            verdict = flag if verdict == "—" else Text.assemble(verdict, "\n", flag)
        chi2 = Text(f"{f.chi2:.0f}/{f.ndof}")
        if not quality[wl].ok:
            chi2.append(" FAILED", style="bold red")
        elif f.error_scale > 1:
            chi2.append(f" (errors ×{f.error_scale:.2f})", style="yellow")
        table.add_row(
            str(wl),
            _length(f.lambda_abs, f.sys_interval_m(0), budget=f.systematics is not None),
            _length(f.lambda_sca, f.sys_interval_m(1), budget=f.systematics is not None),
            f"{f.lambda_att_m:.2f} ± {chk.lambda_att_fit_err_m:.2f}",
            ic,
            verdict,
            phase_text(f),
            chi2,
        )
    console.print(table)
    console.print(
        "values: with a budget, the mean over the template samples its refits used; "
        "errors: fit (statistical and floated nuisances, ×√(χ²/ndof) where that exceeds 1) ± systematic "
        "(+up/−down where the budget is one-sided); "
        "a length the data only bound is a one-sided 95 % CL limit",
        style="dim",
    )
    for _, f in sorted(result.fits.items()):
        if f.systematics is not None:
            print_budget(f)
    for wl, q in sorted(quality.items()):
        if not q.ok:
            console.print(
                labelled(
                    f"{wl} nm fit FAILED:",
                    "bold red",
                    f"{q.reason}. Do not quote λ_abs and λ_sca from it; the χ² per band is in the JSON "
                    "(chi2_bands) and the profile plots (--plots) show where the model misses.",
                )
            )
        phase = result.fits[wl].phase
        if phase is not None:
            console.print(labelled(f"{wl} nm phase function:", "cyan", phase.case_text))
    for wl, chk in sorted(result.checks.items()):
        if chk.flagged:
            console.print(labelled(f"{wl} nm flagged:", "bold red", chk.advice or ""))
        if chk.nuisances_flagged:
            console.print(labelled(f"{wl} nm flagged:", "bold red", chk.nuisance_advice or ""))
        elif chk.nuisance_advice:  # strained at the nominal phase function only
            console.print(labelled(f"{wl} nm note:", "yellow", chk.nuisance_advice))
    for wl, why in sorted(result.notes.items()):
        console.print(labelled(f"{wl} nm:", "yellow", why))
    for wl, why in sorted(result.skipped.items()):
        console.print(labelled(f"{wl} nm skipped:", "yellow", why))


def phase_text(f: ChiSquareFit) -> str:
    """Mie ⟨cos θ⟩ and Rayleigh share as the fit has them: measured, bounded, or held fixed."""
    p = f.phase
    if p is None:
        return f"fixed: g {f.mie_g:g}, Rayleigh {f.rayleigh_share:g}"
    g, r = p.mie_g, p.rayleigh_share
    gt = f"g {g.value:.3f} ± {g.err:.3f}" if g.value is not None and g.err is not None else f"g {p.case}"
    measured = r.value is not None and r.err is not None
    rt = f"Rayleigh {r.value:.2f} ± {r.err:.2f}" if measured else "Rayleigh —"
    return f"{gt}, {rt}"


def _length(e: Estimate, sys_down_up_m: tuple[float, float], *, budget: bool) -> str:
    from analysis.chisq.results import sys_text

    if e.measured:
        if not budget:
            return f"{e.value_m:.2f} ± {e.err_m:.2f} (no budget)"
        return f"{e.value_m:.2f} ± {e.err_m:.2f} {sys_text(sys_down_up_m[1], sys_down_up_m[0])}"
    return e.text("").strip()


def print_budget(f: ChiSquareFit) -> None:
    """One wavelength's systematic budget: each item's error on λ_abs, λ_sca, λ_att."""
    from analysis.chisq.results import cases_text, sys_text

    def err(up: float, down: float) -> str:
        return sys_text(up, down, 3).removeprefix("± ")

    b = f.systematics
    assert b is not None
    table = Table(title=f"{f.wavelength_nm} nm: systematic budget [m]", title_justify="left")
    for col, just in (("varied", "left"), ("cases", "left"), ("λ_abs", "right"), ("λ_sca", "right")):
        table.add_column(col, justify=just)  # type: ignore[arg-type]
    table.add_column("λ_att", justify="right")
    table.add_column("note", justify="left")
    for i in b.items:
        table.add_row(
            i.label,
            cases_text(i.cases),
            *(err(i.up_m[k], i.down_m[k]) for k in range(3)),
            ("floated in the fit: inside its error, not added. " if i.profiled else "") + i.note,
        )
    table.add_row(
        Text("sum in quadrature", style="bold"),
        "",
        *(err(b.sys_up_m(k), b.sys_down_m(k)) for k in range(3)),
        f"{b.seconds:.1f} s",
    )
    console.print(table)
