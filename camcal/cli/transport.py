"""``camcal transport``: the photon transport's own products (c₁/c₂ figure, template cache)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from camcal.cli.common import console, fail, parse_floats, progress_bar
from camcal.cli.defaults import TREX_FOCAL_PX

transport_app = typer.Typer(
    help="Photon transport: the refined model's c1/c2 coefficients, the template cache.",
    no_args_is_help=True,
)


def register(app: typer.Typer) -> None:
    app.add_typer(transport_app, name="transport")


@transport_app.command("c-coefficients")
def c_coefficients(
    out: Annotated[Path, typer.Option(help="Figure to write (PNG).")] = Path("c_coefficients.png"),
    lambda_mie: Annotated[float, typer.Option(help="Mie scattering length [m].")] = 50.0,
    lambda_ray: Annotated[float, typer.Option(help="Rayleigh scattering length [m].")] = 200.0,
    mie_g: Annotated[float, typer.Option(help="Mie <cos theta>.")] = 0.9,
    radii: Annotated[str, typer.Option(help="R range and count for the curves: MIN,MAX,N [m].")] = "5,150,30",
    mc_radii: Annotated[
        str, typer.Option(help="R of the Monte Carlo points [m], comma-separated.")
    ] = "10,25,50,75,100,150",
    photons: Annotated[int, typer.Option(help="Monte Carlo photons per R.")] = 300_000,
    seed: Annotated[int, typer.Option(help="Monte Carlo seed.")] = 0,
) -> None:
    """c₁ = L̄₁/R and c₂ = L̄₂/R (paper, appendix B) by integration, checked by Monte Carlo."""
    import numpy as np

    from analysis.transport.coefficients import ScatteringMix, c1_coefficient, c2_coefficient, sphere_paths_mc
    from camcal.fitplots import plot_c_coefficients

    rng = parse_floats(radii, "--radii")
    if len(rng) != 3 or not 0 < rng[0] < rng[1] or rng[2] < 2:
        raise fail("--radii: give MIN,MAX,N with 0 < MIN < MAX and N >= 2, e.g. 5,150,30")
    try:
        mix = ScatteringMix(lambda_mie, lambda_ray, mie_g)
    except ValueError as exc:
        raise fail(str(exc)) from None
    r = np.linspace(rng[0], rng[1], int(rng[2]))
    with progress_bar("integrating") as update:
        c1, c2 = [], []
        for i, radius in enumerate(r):
            c1.append(c1_coefficient(float(radius), mix))
            c2.append(c2_coefficient(float(radius), mix))
            update(i + 1, len(r))
    mc_r = parse_floats(mc_radii, "--mc-radii") if mc_radii else ()
    with progress_bar("Monte Carlo") as update:
        mc = []
        for i, radius in enumerate(mc_r):
            mc.append(sphere_paths_mc(radius, mix, photons, seed=seed + i))
            update(i + 1, len(mc_r))
    table = Table(
        title=f"λ_mie {lambda_mie:g} m, λ_ray {lambda_ray:g} m, ⟨cos θ⟩ {mie_g:g}", title_justify="left"
    )
    for col in ("R [m]", "c1 (integral)", "c1 (MC)", "pull", "c2 (integral)", "c2 (MC)", "pull"):
        table.add_column(col, justify="right")
    for m in mc:
        i1 = c1_coefficient(m.radius_m, mix)
        i2 = c2_coefficient(m.radius_m, mix)
        table.add_row(
            f"{m.radius_m:g}",
            f"{i1:.4f}",
            f"{m.c1:.4f} ± {m.c1_err:.4f}",
            f"{(m.c1 - i1) / m.c1_err:+.2f}",
            f"{i2:.4f}",
            f"{m.c2:.4f} ± {m.c2_err:.4f}",
            f"{(m.c2 - i2) / m.c2_err:+.2f}",
        )
    console.print(table)
    out.parent.mkdir(parents=True, exist_ok=True)
    title = (
        f"Mean path of once- and twice-scattered photons: λ_mie = {lambda_mie:g} m, "
        f"λ_ray = {lambda_ray:g} m, ⟨cos θ⟩ = {mie_g:g}"
    )
    plot_c_coefficients(r, np.array(c1), np.array(c2), mc, title, out)
    console.print(f"wrote {out}")


@transport_app.command("templates")
def templates(
    near: Annotated[float, typer.Option(help="Near camera's distance [m].")] = 21.56,
    far: Annotated[float, typer.Option(help="Far camera's distance [m].")] = 41.62,
    focal_px: Annotated[float, typer.Option(help="Focal length [px].")] = TREX_FOCAL_PX,
    bands: Annotated[int, typer.Option(help="One-pixel bands per camera (multiple of 8).")] = 152,
    mie_g: Annotated[str, typer.Option(help="Mie <cos theta> nodes, comma-separated.")] = "0.93",
    rayleigh_fraction: Annotated[float, typer.Option(help="Share of scattering that is Rayleigh.")] = 0.17,
    sca_nodes: Annotated[str, typer.Option(help="Scattering-length nodes [m].")] = "12,20,33,55,90,150,250",
    photons: Annotated[int, typer.Option(help="Monte Carlo photons per node.")] = 1_000_000,
    seed: Annotated[int, typer.Option(help="Monte Carlo seed.")] = 0,
    cache_dir: Annotated[Path | None, typer.Option(help="Template cache directory.")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes (default: all cores).")] = 0,
) -> None:
    """Build (or check) the cached templates that ``camcal fit`` will use for this geometry."""
    from analysis.transport.cache import TemplateCache
    from analysis.transport.templates import TemplateSettings, build_template_grid

    try:
        settings = TemplateSettings.near_far(
            near,
            far,
            focal_px,
            n_bands=bands,
            rayleigh_fraction=rayleigh_fraction,
            lambda_sca_nodes_m=tuple(sorted(set(parse_floats(sca_nodes, "--sca-nodes")))),
            mie_g_nodes=tuple(sorted(set(parse_floats(mie_g, "--mie-g")))),
            n_photons=photons,
            seed=seed,
        )
    except ValueError as exc:
        raise fail(str(exc)) from None
    cache = TemplateCache(cache_dir)
    from camcal.core.parallel import process_pool

    with process_pool(workers or os.cpu_count() or 1) as pool, progress_bar("templates") as update:
        grid = build_template_grid(settings, cache, executor=pool, progress=update)
    lo, hi = grid.lambda_sca_range_m
    console.print(
        f"templates in {cache.directory}: λ_sca {lo:.1f}-{hi:.1f} m, ⟨cos θ⟩ {settings.mie_g_nodes}"
    )
