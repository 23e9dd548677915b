"""``camcal simulate-set``: a simulated frame set with its ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from camcal.cli.common import console, fail, parse_floats, parse_mapping, progress_bar

if TYPE_CHECKING:
    from lrm.sim.scene import Water


def register(app: typer.Typer) -> None:
    app.command("simulate-set")(simulate_set)


def build_water(
    preset: str, absorption: str | None, scattering: str | None, mie_g: float, rayleigh_fraction: float
) -> Water:
    """A preset water, with per-wavelength lengths overridden by ``405=39,...`` strings."""
    from analysis.scattering import WaterOptics
    from lrm.sim.scene import Water, water_preset

    try:
        base = water_preset(preset)
    except ValueError as exc:
        raise fail(str(exc)) from None
    abs_map = {int(k): v for k, v in parse_mapping(absorption, "--abs").items()}
    sca_map = {int(k): v for k, v in parse_mapping(scattering, "--sca").items()}
    optics = {}
    for wl, o in base.optics.items():
        try:
            optics[wl] = WaterOptics(
                abs_map.get(wl, o.lambda_abs_m),
                sca_map.get(wl, o.lambda_sca_m),
                mie_g=mie_g,
                rayleigh_fraction=rayleigh_fraction,
            )
        except ValueError as exc:
            raise fail(f"water at {wl} nm: {exc}") from None
    unknown = (set(abs_map) | set(sca_map)) - set(optics)
    if unknown:
        raise fail(f"--abs/--sca: no LEM wavelength {sorted(unknown)} (have 405, 460, 525)")
    custom = bool(abs_map or sca_map)
    return Water(optics, name=f"{preset}+custom" if custom else preset)


def simulate_set(
    out: Annotated[Path, typer.Argument(help="Folder to create the frame set in (must be empty).")],
    water: Annotated[
        str, typer.Option(help="Water preset: trex (~20-28 m), clear (~55 m), turbid (~12 m).")
    ] = "trex",
    absorption: Annotated[
        str | None, typer.Option("--abs", help="Absorption lengths, e.g. 405=39,460=65,525=31 [m].")
    ] = None,
    scattering: Annotated[
        str | None, typer.Option("--sca", help="Scattering lengths, e.g. 405=39,460=50,525=65 [m].")
    ] = None,
    mie_g: Annotated[
        float, typer.Option(help="Mie <cos theta> of the Henyey-Greenstein phase function.")
    ] = 0.93,
    rayleigh_fraction: Annotated[float, typer.Option(help="Fraction of scattering that is Rayleigh.")] = 0.17,
    distance: Annotated[
        list[str] | None, typer.Option(help="Camera distance, CAM=METRES (repeat): A=21.56 B=41.62.")
    ] = None,
    schedule: Annotated[
        str,
        typer.Option(
            help="trex-subsampled (default) or trex (full: 4200 shots); --exposures, --gains, --repeats and"
            " --wavelengths change it."
        ),
    ] = "trex-subsampled",
    exposures: Annotated[str | None, typer.Option(help="Exposures in seconds, e.g. 0.05,0.07,0.11.")] = None,
    gains: Annotated[str | None, typer.Option(help="Gains in dB, e.g. 2,8,14.")] = None,
    repeats: Annotated[int | None, typer.Option(help="Frames per setting.")] = None,
    wavelengths: Annotated[str | None, typer.Option(help="Wavelengths in nm, e.g. 405,460,525.")] = None,
    width: Annotated[int, typer.Option(help="Sensor width [px].")] = 2448,
    height: Annotated[int, typer.Option(help="Sensor height [px].")] = 2048,
    fov_deg: Annotated[float, typer.Option(help="Horizontal field of view in water [deg].")] = 16.0,
    black_level: Annotated[
        float, typer.Option(help="Dark offset of the sensor [gray]; 0: the dark noise is clipped at zero.")
    ] = 2.4,
    read_noise: Annotated[float, typer.Option(help="Read noise of the sensor [electrons].")] = 3.0,
    seed: Annotated[int, typer.Option(help="Seed: the same seed gives the same frames.")] = 0,
    jitter_px: Annotated[float, typer.Option(help="Pointing jitter between frames, one sigma [px].")] = 2.0,
    offset_x: Annotated[float, typer.Option(help="LEM offset from the optical axis, x [px].")] = 0.0,
    offset_y: Annotated[float, typer.Option(help="LEM offset from the optical axis, y [px].")] = 0.0,
    sway: Annotated[float, typer.Option(help="Sway speed of the modules, one sigma [m/s].")] = 0.02,
    flashes: Annotated[float, typer.Option(help="Mean bioluminescence specks per frame.")] = 0.0,
    halo: Annotated[
        str,
        typer.Option(
            help="Halo model: single (fast once-scattered approximation) or transport "
            "(photon transport, the χ² fit's physics; computed once, then cached)."
        ),
    ] = "single",
    halo_orders: Annotated[
        int,
        typer.Option(
            help="With --halo transport: scattering orders followed (twice the fit templates' 6, so the "
            "frames are a truth the templates did not make; their Monte Carlo seed differs too)."
        ),
    ] = 12,
    halo_photons: Annotated[
        int, typer.Option(help="With --halo transport: Monte Carlo photons per camera and wavelength.")
    ] = 1_000_000,
    halo_table: Annotated[
        list[Path] | None,
        typer.Option(
            help="A halo another engine rendered (Mitsuba 3, bench/mitsuba_halo.py; repeat, one per "
            "wavelength, e.g. tests/data/mitsuba/ff-460.npz): its water and phase function replace --water/"
            "--abs/--sca/--mie-g/--rayleigh-fraction, the LEM is uniform (I0'/I0 = 1), the wavelengths are "
            "the tables'."
        ),
    ] = None,
    psf_jitter: Annotated[
        str | None,
        typer.Option(
            help="A blur drawn per frame: the Gaussian PSF σ uniform in LOW,HIGH px (e.g. 0.8,2.0), recorded "
            "per frame in truth.json; default: the camera's one PSF."
        ),
    ] = None,
    streaks: Annotated[
        float,
        typer.Option(help="With --psf-jitter: share of frames with a motion streak in a random direction."),
    ] = 1.0 / 3.0,
    streak_px: Annotated[str, typer.Option(help="With --psf-jitter: streak length LOW,HIGH [px].")] = "2,6",
    workers: Annotated[int, typer.Option(help="Worker processes (default: all cores).")] = 0,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Simulate a dive's frame set (manifest, setup.json, PNGs) and its ground truth (truth.json)."""
    from camcal.core.schedule import Schedule, trex_schedule, trex_subsampled
    from lrm.sim.blur import PsfJitter
    from lrm.sim.camera import CameraModel
    from lrm.sim.halotable import HaloTable, tables_by_wavelength
    from lrm.sim.render import TransportHalo
    from lrm.sim.scene import TREX_PLACEMENTS, Placement
    from lrm.simset import SimulationSpec, simulate_frame_set, table_spec

    jitter = None
    if psf_jitter is not None:
        try:
            sig, lengths = parse_floats(psf_jitter, "--psf-jitter"), parse_floats(streak_px, "--streak-px")
            if len(sig) != 2 or len(lengths) != 2:
                raise ValueError("--psf-jitter and --streak-px take two numbers, LOW,HIGH")
            jitter = PsfJitter((sig[0], sig[1]), streaks, (lengths[0], lengths[1]))
        except ValueError as exc:
            raise fail(str(exc)) from None
    tables: list[HaloTable] = []
    if halo_table:
        if absorption or scattering:
            raise fail("--halo-table gives the water: leave out --abs and --sca")
        try:
            tables = [HaloTable.load(p) for p in halo_table]
            by_wl = tables_by_wavelength(tables)
        except (OSError, KeyError, ValueError) as exc:
            raise fail(f"--halo-table: {exc}") from None
        if not wavelengths:
            wavelengths = ",".join(str(w) for w in sorted(by_wl))
    if halo not in ("single", "transport"):
        raise fail(f"--halo: unknown halo model {halo!r} (single, transport)")
    if not 2 <= halo_orders <= 30 or halo_photons < 10_000:
        raise fail("--halo-orders must lie in 2..30 and --halo-photons be >= 10000")
    w = build_water(water, absorption, scattering, mie_g, rayleigh_fraction)
    distances = parse_mapping(distance, "--distance")
    placements = list(TREX_PLACEMENTS)
    if distances:
        ordered = sorted(distances.items(), key=lambda kv: kv[1])
        if len(ordered) != 2:
            raise fail("--distance: give exactly two cameras, e.g. --distance A=21.56 --distance B=41.62")
        try:
            placements = [
                Placement(ordered[0][0], ordered[0][1], 0.02, faces_far_side=False),
                Placement(ordered[1][0], ordered[1][1], 0.04, faces_far_side=True),
            ]
        except ValueError as exc:
            raise fail(str(exc)) from None
    base = {"trex": trex_schedule, "trex-subsampled": trex_subsampled}.get(schedule)
    if base is None:
        raise fail(f"--schedule: unknown schedule {schedule!r} (trex, trex-subsampled)")
    sched = base()
    try:
        sched = Schedule(
            name=sched.name if not (exposures or gains or repeats or wavelengths) else "custom",
            exposures_s=parse_floats(exposures, "--exposures") if exposures else sched.exposures_s,
            gains_db=parse_floats(gains, "--gains") if gains else sched.gains_db,
            repeats=repeats if repeats is not None else sched.repeats,
            wavelengths_nm=tuple(int(x) for x in parse_floats(wavelengths, "--wavelengths"))
            if wavelengths
            else sched.wavelengths_nm,
        )
        camera = CameraModel(
            width_px=width,
            height_px=height,
            fov_deg=fov_deg,
            black_level_gray=black_level,
            read_noise_e=read_noise,
        )
        for e in sched.exposures_s:
            for g in sched.gains_db:
                camera.check_setting(e, g)
    except ValueError as exc:
        raise fail(str(exc).splitlines()[0] if "validation error" not in str(exc) else _pyd(exc)) from None
    common = {
        "placements": tuple(placements),
        "camera": camera,
        "seed": seed,
        "jitter_px": jitter_px,
        "offset_px": (offset_x, offset_y),
        "sway_m_per_s": sway,
        "flashes_per_frame": flashes,
        "psf_jitter": jitter,
    }
    if tables:
        try:
            spec = table_spec(tables, sched, **common)
        except ValueError as exc:
            raise fail(f"--halo-table: {exc}") from None
        w = spec.water
    else:
        spec = SimulationSpec(
            water=w,
            schedule=sched,
            halo_model=halo,
            transport=TransportHalo(n_photons=halo_photons, max_order=halo_orders)
            if halo == "transport"
            else None,
            **common,  # type: ignore[arg-type]
        )
    n = sched.n_frames * len(placements)
    console.print(
        f"simulating {n} frames ({sched.n_frames} shots x {len(placements)} cameras) "
        f"of {width} x {height} px in {w.name} water into {out}"
    )
    try:
        with progress_bar("rendering", quiet=quiet) as update:
            truth = simulate_frame_set(out, spec, workers=workers or None, progress=update)
    except FileExistsError as exc:
        raise fail(str(exc)) from None
    truth_water = truth["water"]
    assert isinstance(truth_water, dict)
    for wl_name, o in truth_water.items():
        console.print(
            f"  {wl_name} nm: λ_abs {o['lambda_abs_m']:.1f} m, λ_sca {o['lambda_sca_m']:.1f} m "
            f"-> λ_att {o['lambda_att_m']:.2f} m"
        )
    console.print(f"wrote {out}/manifest.csv, setup.json, truth.json")


def _pyd(exc: ValueError) -> str:
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        e = exc.errors()[0]
        return f"schedule {'.'.join(str(p) for p in e['loc'])}: {e['msg']}"
    return str(exc)
