"""``camcal simulate-lab``: a simulated lab frame set for one calibration, with its truth."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from camcal.cli.common import console, fail, parse_floats, parse_mapping, progress_bar
from camcal.cli.defaults import LAB_KINDS

if TYPE_CHECKING:
    from lrm.sim.scene import Water


def register(app: typer.Typer) -> None:
    app.command("simulate-lab")(simulate_lab)


def _tank_water(absorption: str | None, scattering: str | None) -> Water:
    """The tank's tap water with per-wavelength lengths replaced by ``405=8,...`` strings."""
    from analysis.scattering import WaterOptics
    from lrm.sim.lab import tap_water
    from lrm.sim.scene import Water

    base = tap_water()
    abs_map = {int(k): v for k, v in parse_mapping(absorption, "--abs").items()}
    sca_map = {int(k): v for k, v in parse_mapping(scattering, "--sca").items()}
    optics = {}
    for wl in sorted(set(base.optics) | set(abs_map) | set(sca_map)):
        o = base.optics.get(wl)
        a = abs_map.get(wl, o.lambda_abs_m if o else None)
        s = sca_map.get(wl, o.lambda_sca_m if o else None)
        if a is None or s is None:
            raise fail(f"--abs/--sca: {wl} nm needs both an absorption and a scattering length")
        try:
            optics[wl] = WaterOptics(a, s)
        except ValueError as exc:
            raise fail(f"water at {wl} nm: {exc}") from None
    return Water(optics, name="tap+custom" if abs_map or sca_map else base.name)


def simulate_lab(
    kind: Annotated[str, typer.Argument(help=f"The experiment: {', '.join(LAB_KINDS)}.")],
    out: Annotated[Path, typer.Argument(help="Folder to create the frame set in (must be empty).")],
    seed: Annotated[int, typer.Option(help="Seed: the same seed gives the same frames.")] = 0,
    repeats: Annotated[int, typer.Option(help="Frames per setting (per distance, per side...).")] = 2,
    width: Annotated[int, typer.Option(help="Sensor width [px].")] = 2448,
    height: Annotated[int, typer.Option(help="Sensor height [px].")] = 2048,
    fov_deg: Annotated[float, typer.Option(help="Horizontal field of view [deg].")] = 16.0,
    psf_sigma: Annotated[float, typer.Option(help="The camera's PSF width, one sigma [px].")] = 1.2,
    gain: Annotated[float | None, typer.Option(help="Gain [dB] (default: the experiment's).")] = None,
    wavelengths: Annotated[str | None, typer.Option(help="Wavelengths [nm], e.g. 405,460,525.")] = None,
    distances: Annotated[str | None, typer.Option(help="Scan distances [m], e.g. 5.2,10,20,41.2.")] = None,
    distance_err: Annotated[float | None, typer.Option(help="Distance reading error [m].")] = None,
    temperatures: Annotated[str | None, typer.Option(help="Temperature runs [°C], e.g. 2.1,18.9.")] = None,
    absorption: Annotated[
        str | None, typer.Option("--abs", help="Tank water absorption [m], 460=12.")
    ] = None,
    scattering: Annotated[
        str | None, typer.Option("--sca", help="Tank water scattering [m], 460=20.")
    ] = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Simulate a lab calibration: linearity, emission-ratio, air-scan, tank-scan or psf (+ truth.json)."""
    from lrm.labset import SPEC_CLASSES, lab_spec, write_lab_set
    from lrm.sim.camera import CameraModel

    if kind not in SPEC_CLASSES:
        raise fail(f"KIND: unknown experiment {kind!r}; choose from {', '.join(LAB_KINDS)}")
    fields = set(SPEC_CLASSES[kind].__dataclass_fields__)
    values: dict[str, Any] = {"seed": seed, "repeats": repeats}
    given = {
        "--wavelengths": ("wavelengths_nm", wavelengths),
        "--distances": ("distances_m", distances),
        "--distance-err": ("distance_err_m", distance_err),
        "--temperatures": ("temperatures_c", temperatures),
        "--gain": ("gain_db", gain),
    }
    for option, (name, raw) in given.items():
        if raw is None:
            continue
        if name == "wavelengths_nm" and "wavelength_nm" in fields:
            nm = parse_floats(str(raw), option)
            if len(nm) != 1:
                raise fail(f"{option}: {kind} uses one wavelength, got {len(nm)}")
            values["wavelength_nm"] = int(nm[0])
            continue
        if name not in fields:
            raise fail(f"{option} does not apply to {kind}")
        if isinstance(raw, str):
            parsed = parse_floats(raw, option)
            values[name] = tuple(int(v) for v in parsed) if name == "wavelengths_nm" else parsed
        else:
            values[name] = raw
    if absorption or scattering:
        if "water" not in fields:
            raise fail(f"--abs/--sca apply to tank-scan only, not {kind}")
        values["water"] = _tank_water(absorption, scattering)
    try:
        values["camera"] = replace(
            CameraModel(width_px=width, height_px=height, fov_deg=fov_deg), psf_sigma_px=psf_sigma
        )
        spec = lab_spec(kind, **values)
        n = len(spec.shots())
    except ValueError as exc:
        raise fail(str(exc)) from None
    console.print(f"simulating {n} {kind} frames of {width} x {height} px into {out}")
    try:
        with progress_bar("rendering", quiet=quiet) as update:
            write_lab_set(out, spec, progress=update)
    except (FileExistsError, ValueError) as exc:
        raise fail(str(exc)) from None
    console.print(f"wrote {out}/manifest.csv, setup.json, truth.json")
