"""Write a simulated frame set with its ground truth.

Both cameras take every shot of the schedule, as the two T-REX LRMs did.
Each frame's randomness comes from ``(seed, frame index)``, so the set is the
same whatever the number of worker processes.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from camcal.core.files import write_atomic
from camcal.core.frameset import (
    MANIFEST,
    CameraSetup,
    ManifestRow,
    RatioSetup,
    Setup,
)
from camcal.core.framewriter import FrameSetWriter
from camcal.core.images import encode_png
from camcal.core.parallel import process_pool
from camcal.core.schedule import Schedule, trex_subsampled
from lrm.sim.blur import PsfJitter
from lrm.sim.camera import CameraModel
from lrm.sim.halotable import HaloTable, tables_by_wavelength
from lrm.sim.render import FrameRenderer, TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, LEMModel, Placement, Water, water_preset

TRUTH = "truth.json"
#: Calibration values the T-REX lab measured (what setup.json claims by default).
LAB_RATIO_ERR = {405: 0.03, 460: 0.04, 525: 0.04}


@dataclass(frozen=True)
class SimulationSpec:
    """Everything that determines a simulated frame set.

    ``psf_jitter``: a blur drawn per frame (PSF σ, a motion streak on some
    frames) instead of the camera's one PSF; each frame's is in truth.json.
    """

    water: Water = field(default_factory=lambda: water_preset("trex"))
    placements: tuple[Placement, ...] = TREX_PLACEMENTS
    camera: CameraModel = field(default_factory=CameraModel)
    lem: LEMModel = field(default_factory=LEMModel)
    schedule: Schedule = field(default_factory=trex_subsampled)
    seed: int = 0
    jitter_px: float = 2.0
    offset_px: tuple[float, float] = (0.0, 0.0)
    sway_m_per_s: float = 0.02
    depth_m: float = 3420.0
    start: datetime = datetime(2021, 9, 10, 4, 0, 0, tzinfo=UTC)
    double_image_cameras: tuple[str, ...] = ("A",)
    flashes_per_frame: float = 0.0
    lem_on: bool = True
    halo_model: str = "single"
    transport: TransportHalo | None = None
    psf_jitter: PsfJitter | None = None

    def setup(self) -> Setup:
        """The setup.json a lab would write: true distances, lab-calibrated ratios."""
        return Setup(
            cameras={
                p.camera: CameraSetup(distance_m=p.distance_m, distance_err_m=p.distance_err_m)
                for p in self.placements
            },
            emission_ratio={
                wl: RatioSetup(value=float(v), err=LAB_RATIO_ERR.get(wl, 0.03))
                for wl, v in self.lem.emission_ratio.items()
            },
            linear_range=(5.0, 240.0),
            focal_px=self.camera.focal_px,
            lem_diameter_m=self.lem.diameter_m,
        )


@dataclass(frozen=True)
class _Job:
    index: int
    camera: str
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    file: str


_RENDERERS: dict[tuple[int, str], FrameRenderer] = {}
_WORKER: dict[str, object] = {}


def _renderer(spec: SimulationSpec, camera: str) -> FrameRenderer:
    key = (id(spec), camera)
    if key not in _RENDERERS:
        placement = next(p for p in spec.placements if p.camera == camera)
        _RENDERERS[key] = FrameRenderer(
            spec.camera,
            placement,
            spec.water,
            spec.lem,
            seed=spec.seed,
            double_image=camera in spec.double_image_cameras,
            halo_model=spec.halo_model,
            transport=spec.transport,
        )
    return _RENDERERS[key]


def render_job(spec: SimulationSpec, job: _Job) -> tuple[np.ndarray, dict[str, object]]:
    """Render one frame of the set: pointing jitter and sway drawn from (seed, index)."""
    rng = np.random.default_rng([spec.seed, job.index])
    renderer = _renderer(spec, job.camera)
    offset = (
        spec.offset_px[0] + rng.normal(0, spec.jitter_px),
        spec.offset_px[1] + rng.normal(0, spec.jitter_px),
    )
    angle = rng.uniform(0, 2 * math.pi)
    speed = abs(rng.normal(0, spec.sway_m_per_s))
    placement = renderer.placement
    length = speed * job.exposure_s / placement.distance_m * spec.camera.focal_px
    blur = (length * math.cos(angle), length * math.sin(angle))
    psf = None
    if spec.psf_jitter is not None:  # drawn after the sway: sets without it are unchanged
        psf, streak = spec.psf_jitter.draw(rng)
        blur = (blur[0] + streak[0], blur[1] + streak[1])
    frame, truth = renderer.render(
        job.wavelength_nm,
        job.exposure_s,
        job.gain_db,
        rng=rng,
        offset_px=offset,
        blur_px=blur,
        lem_on=spec.lem_on,
        flashes_per_frame=spec.flashes_per_frame,
        psf_sigma_px=psf,
    )
    return frame, {"file": job.file, **truth.to_dict()}


def _init_worker(spec: SimulationSpec, folder: str) -> None:
    _WORKER["spec"], _WORKER["folder"] = spec, folder


def _work(job: _Job) -> dict[str, object]:
    spec = _WORKER["spec"]
    assert isinstance(spec, SimulationSpec)
    frame, truth = render_job(spec, job)
    write_atomic(Path(str(_WORKER["folder"])) / job.file, encode_png(frame), fsync=False)
    return truth


def plan_jobs(spec: SimulationSpec) -> list[_Job]:
    """The frames of one pass: each shot of the schedule, taken by every camera."""
    jobs: list[_Job] = []
    seq = {p.camera: 0 for p in spec.placements}
    for shot in spec.schedule.shots():
        for p in spec.placements:
            seq[p.camera] += 1
            name = f"{p.camera}_{shot.wavelength_nm}_{seq[p.camera]:05d}.png"
            jobs.append(_Job(len(jobs), p.camera, shot.wavelength_nm, shot.exposure_s, shot.gain_db, name))
    return jobs


def simulate_frame_set(
    out: Path,
    spec: SimulationSpec,
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, object]:
    """Render the set into ``out`` (manifest.csv, setup.json, PNGs, truth.json).

    Returns the truth dictionary that is also written to ``truth.json``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if (out / MANIFEST).exists():
        raise FileExistsError(f"{out} already holds a frame set; choose an empty folder")
    jobs = plan_jobs(spec)
    workers = workers or os.cpu_count() or 1
    if spec.halo_model == "transport":
        # Compute (or load) each camera's transport halo once here, so that the worker
        # processes find it in the cache instead of all computing it at once.
        for p in spec.placements:
            for wl in spec.schedule.wavelengths_nm:
                _renderer(spec, p.camera).halo_table(wl)
    truths: list[dict[str, object]] = [{}] * len(jobs)
    done = 0
    if workers <= 1:
        _init_worker(spec, str(out))
        results = map(_work, jobs)
        for job, truth in zip(jobs, results, strict=True):
            truths[job.index] = truth
            done += 1
            if progress:
                progress(done, len(jobs))
    else:
        with process_pool(workers, _init_worker, (spec, str(out))) as pool:
            for job, truth in zip(jobs, pool.map(_work, jobs, chunksize=2), strict=True):
                truths[job.index] = truth
                done += 1
                if progress:
                    progress(done, len(jobs))
    _write_manifest(out, spec, jobs)
    truth_doc = truth_document(spec, truths)
    write_atomic(out / TRUTH, (json.dumps(truth_doc, indent=1) + "\n").encode(), fsync=False)
    return truth_doc


def _write_manifest(out: Path, spec: SimulationSpec, jobs: Sequence[_Job]) -> None:
    clock = spec.start
    with FrameSetWriter(out, spec.setup()) as writer:
        for job in jobs:
            row = ManifestRow(
                index=job.index,
                file=job.file,
                camera=job.camera,
                wavelength_nm=job.wavelength_nm,
                exposure_s=job.exposure_s,
                gain_db=job.gain_db,
                timestamp=clock.isoformat().replace("+00:00", "Z"),
                depth_m=spec.depth_m,
                seq=int(job.file.rsplit("_", 1)[1].split(".")[0]),
            )
            writer.record(row)  # the image is on disk already
            if job.camera == spec.placements[-1].camera:
                clock += timedelta(seconds=job.exposure_s + 0.25)


def table_spec(tables: list[HaloTable], schedule: Schedule | None = None, **kw: Any) -> SimulationSpec:
    """A frame set whose halo at each wavelength is another engine's table (Mitsuba 3's).

    The water is the tables' (one per wavelength, which each records), the
    LEM uniform (the tables' emitter: I0'/I0 = 1), the halo model
    ``transport`` with the tables. ``schedule`` (default: the subsampled
    T-REX one) is taken at the tables' wavelengths, or refused if it names
    one without a table; ``kw`` sets the rest of the spec.
    """
    by_wl = tables_by_wavelength(tables)
    if schedule is None:
        schedule = trex_subsampled().model_copy(update={"wavelengths_nm": tuple(sorted(by_wl))})
        schedule = Schedule.model_validate(schedule.model_dump())
    missing = sorted(set(schedule.wavelengths_nm) - set(by_wl))
    if missing:
        have = ", ".join(str(w) for w in sorted(by_wl))
        raise ValueError(f"no halo table at {', '.join(map(str, missing))} nm (the tables are at {have} nm)")
    used = [by_wl[wl] for wl in sorted(schedule.wavelengths_nm)]
    return SimulationSpec(
        water=Water(
            {t.wavelength_nm: t.water for t in used if t.wavelength_nm}, name="+".join(t.name for t in used)
        ),
        lem=LEMModel(emission_ratio={wl: 1.0 for wl in schedule.wavelengths_nm}),
        schedule=schedule,
        halo_model="transport",
        transport=TransportHalo(tables=tuple(used)),
        **kw,
    )


def truth_document(spec: SimulationSpec, frames: list[dict[str, object]]) -> dict[str, object]:
    """Ground truth: the water, the geometry, the true emission ratios, the blur and every frame.

    Per wavelength the water's ``mean_cos_theta`` is (1 − rayleigh_fraction)
    · mie_g (Rayleigh's mean cosine is 0); with halo tables, ``phase`` holds
    each table's phase function (its family: a non-HG one's mie_g is its
    particles' mean cosine) and where it came from.
    """
    tables = spec.transport.tables if spec.transport is not None else ()
    doc: dict[str, object] = {
        "water": {
            str(wl): {
                **asdict(o),
                "lambda_att_m": o.lambda_att_m,
                "mean_cos_theta": (1.0 - o.rayleigh_fraction) * o.mie_g,
            }
            for wl, o in sorted(spec.water.optics.items())
        },
        "water_name": spec.water.name,
        "cameras": {
            p.camera: {"distance_m": p.distance_m, "faces_far_side": p.faces_far_side}
            for p in spec.placements
        },
        "emission_ratio": {str(k): v for k, v in spec.lem.emission_ratio.items()},
        "camera_model": {**asdict(spec.camera), "focal_px": spec.camera.focal_px},
        "seed": spec.seed,
        "schedule": spec.schedule.model_dump(mode="json"),
        "psf_jitter": asdict(spec.psf_jitter) if spec.psf_jitter is not None else None,
    }
    if tables:
        doc["phase"] = {
            str(t.wavelength_nm): {
                **(t.phase.to_dict() if t.phase is not None else {}),
                "halo_table": t.name,
                "engine": "Mitsuba 3 volpath (bench/mitsuba_halo.py)",
                "spp": t.spp,
            }
            for t in tables
        }
    doc["frames"] = frames
    return doc
