"""A whole T-REX dive in simulated time: frames and sensor samples at any instant.

`DiveSimulation` ties together the dive's timeline (`DiveProfile`), the
LEM's colour cycle (`LEMTimetable`), the water column (`WaterColumn`), each
module's motion (`ModuleMotion`) and housing (`HousingModel`), and the
frame renderer of `lrm.sim`. Everything is a deterministic function of the
seed and the dive time, so a camera thread and a sensor thread asking in any
order, or a test asking again, get the same answers.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import replace
from datetime import UTC, datetime, timedelta

import numpy as np

from lrm.dive._random import hashed_normal, stable_key
from lrm.dive.housing import HousingModel, HousingParams
from lrm.dive.motion import Attitude, ModuleMotion, MotionParams
from lrm.dive.profile import DiveProfile, LEMTimetable
from lrm.dive.water import WaterColumn
from lrm.sensors import SensorSample
from lrm.sim.camera import CameraModel
from lrm.sim.render import FrameRenderer
from lrm.sim.scene import TREX_PLACEMENTS, LEMModel, Placement, Water

#: Dive time 0 of the default simulation (T-REX went down in September 2021).
DEFAULT_START = datetime(2021, 9, 10, 4, 0, 0, tzinfo=UTC)
#: Gauge pressure per metre of sea water (ρ g with ρ = 1030 kg/m³), decibar;
#: compressibility (+0.6 % at 3.4 km) is left out.
DBAR_PER_M = 1030.0 * 9.81 / 1e4


def scaled_camera(camera: CameraModel, frame_scale: float) -> CameraModel:
    """A smaller sensor cut from the middle of ``camera``, with the same plate scale.

    Width and height shrink by ``frame_scale``; the field of view shrinks with
    them so that the focal length in pixels, and hence the LEM's size in
    pixels and its shift for a given tilt, stay those of the full sensor.
    """
    if not (0 < frame_scale <= 1):
        raise ValueError(f"frame_scale must lie in (0, 1], got {frame_scale}")
    if frame_scale == 1:
        return camera
    width = max(round(camera.width_px * frame_scale), 16)
    height = max(round(camera.height_px * frame_scale), 16)
    fov_deg = 2.0 * math.degrees(math.atan((width / 2.0) / camera.focal_px))
    return replace(camera, width_px=width, height_px=height, fov_deg=fov_deg)


class DiveSimulation:
    """A T-REX dive, deterministic from ``seed``: what each module's camera and sensors see.

    Parameters
    ----------
    profile, timetable, water_column
        The dive's timeline, the LEM's colour cycle and the water (defaults:
        the T-REX dive, 60 s per colour, the default column).
    placements
        Where the modules hang above the LEM (default: T-REX, A at 21.56 m
        and B at 41.62 m). A module's depth is the LEM's minus its distance.
    camera
        The full-size camera model of every module.
    lem
        The light emitter.
    seed
        Seeds every random draw of the dive (motion, sensor noise, frame noise).
    sensor_rate_hz
        Rate of the housing sensors; samples sit on a grid of this rate.
    frame_scale
        Renders a smaller sensor for fast runs, e.g. 0.25 gives 612 x 512 px
        instead of 2448 x 2048. The **plate scale is kept**: the focal length
        in pixels is the full sensor's, so the LEM keeps its size in pixels
        and a tilt moves it by as many pixels as on the full sensor; the
        small frame is the middle of the full one, with a 4x narrower view,
        so a lean that the full sensor tolerates can push the LEM off it.
    start
        The UTC datetime of dive time 0.
    motion_params, tilt_scale
        Motion of the modules; ``tilt_scale`` maps module ids to a factor on
        their tilt (e.g. ``{"B": 6.0}`` to make B lean too far).
    housing_params, leak_at_s
        The housings; ``leak_at_s`` maps module ids to the dive time at which
        water starts getting in (humidity then rises).
    double_image_cameras
        Modules whose dome doubles the LEM near the edge of the view (T-REX: A).
    flashes_per_frame
        Mean number of bioluminescent specks per frame.
    renderer_cache_size
        Renderers kept (least recently used are dropped). One renderer serves
        one module in one quantised water state, see `render`; at full size
        each holds ~30 MB (its noise bank) and takes ~0.3 s to build.
    water_weight_step, drift_step
        Quantisation of the water column's depth weight and drift factor
        between renderers (`water_state`): a step changes λ_att by at most
        ~0.4 %, so the rendered water is within ~0.2 % of the column's; the
        frames report the value rendered and the exact one.
    acc_noise_m_s2, gyro_noise_dps, gyro_bias_dps
        White noise per sample of the accelerometer (~2 mg) and gyroscope, and
        the RMS of the gyroscope's fixed bias (drawn per module).
    """

    def __init__(
        self,
        profile: DiveProfile | None = None,
        timetable: LEMTimetable | None = None,
        water_column: WaterColumn | None = None,
        placements: Sequence[Placement] = TREX_PLACEMENTS,
        camera: CameraModel | None = None,
        lem: LEMModel | None = None,
        seed: int = 0,
        sensor_rate_hz: float = 10.0,
        frame_scale: float = 1.0,
        *,
        start: datetime = DEFAULT_START,
        motion_params: MotionParams | None = None,
        tilt_scale: Mapping[str, float] | None = None,
        housing_params: HousingParams | None = None,
        leak_at_s: Mapping[str, float] | None = None,
        double_image_cameras: Sequence[str] = ("A",),
        flashes_per_frame: float = 0.0,
        renderer_cache_size: int = 8,
        water_weight_step: float = 0.004,
        drift_step: float = 0.004,
        acc_noise_m_s2: float = 0.02,
        gyro_noise_dps: float = 0.02,
        gyro_bias_dps: float = 0.05,
    ) -> None:
        if start.tzinfo is None or start.utcoffset() is None:
            raise ValueError(f"start must be timezone-aware UTC, got naive {start.isoformat()}")
        if not (sensor_rate_hz > 0 and math.isfinite(sensor_rate_hz)):
            raise ValueError(f"sensor_rate_hz must be > 0, got {sensor_rate_hz}")
        if renderer_cache_size < 1:
            raise ValueError(f"renderer_cache_size must be >= 1, got {renderer_cache_size}")
        if not (water_weight_step > 0 and drift_step > 0):
            raise ValueError(
                f"water_weight_step and drift_step must be > 0, got {water_weight_step}, {drift_step}"
            )
        self.profile = profile or DiveProfile()
        self.timetable = timetable or LEMTimetable()
        self.water_column = water_column or WaterColumn()
        self.placements = {p.camera: p for p in placements}
        if len(self.placements) != len(placements):
            raise ValueError(f"placements has repeated camera ids: {[p.camera for p in placements]}")
        self.full_camera = camera or CameraModel()
        self.frame_scale = float(frame_scale)
        self.camera = scaled_camera(self.full_camera, self.frame_scale)
        self.lem = lem or LEMModel()
        self.seed = int(seed)
        self.sensor_rate_hz = float(sensor_rate_hz)
        self.start = start.astimezone(UTC)
        self.double_image_cameras = tuple(double_image_cameras)
        self.flashes_per_frame = float(flashes_per_frame)
        self.water_weight_step = float(water_weight_step)
        self.drift_step = float(drift_step)
        for name, mapping in (("tilt_scale", tilt_scale), ("leak_at_s", leak_at_s)):
            unknown = set(mapping or {}) - set(self.placements)
            if unknown:
                raise ValueError(f"{name} names unknown modules {sorted(unknown)}; known: {self.module_ids}")
        self.motions = {
            m: ModuleMotion(
                m, self.seed, self.profile, tilt_scale=(tilt_scale or {}).get(m, 1.0), params=motion_params
            )
            for m in self.placements
        }
        self.housings = {
            m: HousingModel(self.profile, p.distance_m, housing_params, (leak_at_s or {}).get(m))
            for m, p in self.placements.items()
        }
        self._noise_keys = {m: stable_key(self.seed, "sensors", m) for m in self.placements}
        self.acc_noise_m_s2 = float(acc_noise_m_s2)
        self.gyro_noise_dps = float(gyro_noise_dps)
        self._gyro_bias = {
            m: gyro_bias_dps * hashed_normal(self._noise_keys[m], np.arange(3), channel=99)
            for m in self.placements
        }
        self._renderers: OrderedDict[tuple[str, int, int], FrameRenderer] = OrderedDict()
        self._cache_size = int(renderer_cache_size)
        self._lock = threading.Lock()
        self.renderers_built = 0

    # -- time and place ------------------------------------------------------
    @property
    def module_ids(self) -> list[str]:
        return list(self.placements)

    def placement(self, module: str) -> Placement:
        try:
            return self.placements[module]
        except KeyError:
            raise ValueError(f"module {module!r} is not in this dive; modules: {self.module_ids}") from None

    def dive_time_s(self, when: datetime) -> float:
        """Dive time (s since ``start``) of a UTC datetime."""
        if when.tzinfo is None or when.utcoffset() is None:
            raise ValueError(f"when must be timezone-aware UTC, got naive {when.isoformat()}")
        return (when - self.start).total_seconds()

    def time_at(self, t_s: float) -> datetime:
        """The UTC datetime of dive time ``t_s``."""
        return self.start + timedelta(seconds=t_s)

    @property
    def heave_period_s(self) -> float:
        """Dominant period of the ship's heave (common to all modules)."""
        return next(iter(self.motions.values())).heave_period_s

    def module_depth_m(self, module: str, t_s: float) -> float:
        """Depth of a module: the LEM's minus its distance, plus the heave; 0 out of the water."""
        distance = self.placement(module).distance_m
        depth = self.profile.lem_depth_at(t_s) - distance
        if depth <= 0:
            return 0.0
        return max(depth - float(self.motions[module].heave_displacement_m(np.array([t_s]))[0]), 0.0)

    def attitude(self, module: str, t_s: float) -> Attitude:
        self.placement(module)
        return self.motions[module].attitude_at(t_s)

    # -- water truth ---------------------------------------------------------
    def path_depth_m(self, module: str, t_s: float) -> float:
        """Depth of the middle of the light path from the LEM to a module's camera."""
        return WaterColumn.path_midpoint_depth_m(
            self.profile.lem_depth_at(t_s), self.placement(module).distance_m
        )

    def water_truth(self, module: str, t_s: float) -> Water:
        """The column's exact water on a module's light path at dive time ``t_s``."""
        return self.water_column.water_at(self.path_depth_m(module, t_s), t_s)

    def lambda_att_truth_m(self, module: str, wavelength_nm: int, t_s: float) -> float:
        """The column's exact λ_att on a module's light path (not quantised)."""
        return self.water_truth(module, t_s).at(wavelength_nm).lambda_att_m

    def lambda_att_pair_truth_m(
        self, wavelength_nm: int, t_s: float, near: str = "A", far: str = "B"
    ) -> float:
        """The λ_att the I_center method should find from a near/far pair at ``t_s``.

        With each path in its own water, ``ln(I_near / I_far · I0'/I0) =
        L_far / λ_far - L_near / λ_near``, so the pair measures
        ``(L_far - L_near) / (L_far / λ_far - L_near / λ_near)``: the water of
        the stretch between the two cameras. Uses the exact column.
        """
        ln, lf = self.placement(near).distance_m, self.placement(far).distance_m
        an = self.lambda_att_truth_m(near, wavelength_nm, t_s)
        af = self.lambda_att_truth_m(far, wavelength_nm, t_s)
        return (lf - ln) / (lf / af - ln / an)

    # -- sensors -------------------------------------------------------------
    def sensor_index(self, t_s: float) -> int:
        """Index of the latest sensor sample at or before dive time ``t_s``."""
        return math.floor(t_s * self.sensor_rate_hz + 1e-9)

    def sensor_series(self, module: str, t0_s: float, t1_s: float) -> dict[str, np.ndarray]:
        """Every sensor sample of a module with ``t0_s <= t < t1_s``, as arrays.

        Keys: ``t_s`` (n), ``acc_m_s2`` (n, 3), ``gyro_dps`` (n, 3),
        ``temperature_c``, ``humidity_pct``, ``depth_m``, ``pressure_dbar``
        (n). The same samples as `sensor_sample`, computed together.
        """
        k0 = math.ceil(t0_s * self.sensor_rate_hz - 1e-9)
        k1 = math.ceil(t1_s * self.sensor_rate_hz - 1e-9)
        return self._samples(module, np.arange(k0, max(k1, k0), dtype=np.int64))

    def _samples(self, module: str, index: np.ndarray) -> dict[str, np.ndarray]:
        placement = self.placement(module)
        motion, housing = self.motions[module], self.housings[module]
        hp = housing.params
        key = self._noise_keys[module]
        t = index / self.sensor_rate_hz

        def noise(channel: int, sigma: float) -> np.ndarray:
            return sigma * hashed_normal(key, index, channel)

        acc = motion.specific_force_m_s2(t)
        gyro = motion.rates_dps(t) + self._gyro_bias[module]
        for axis in range(3):
            acc[:, axis] += noise(axis, self.acc_noise_m_s2)
            gyro[:, axis] += noise(3 + axis, self.gyro_noise_dps)
        depth = self.profile.lem_depths_m(t) - placement.distance_m
        depth = np.where(depth > 0, np.maximum(depth - motion.heave_displacement_m(t), 0.0), 0.0)
        return {
            "t_s": t,
            "acc_m_s2": acc,
            "gyro_dps": gyro,
            "temperature_c": housing.temperature_c(t) + noise(6, hp.temperature_noise_c),
            "humidity_pct": np.clip(housing.humidity_pct(t) + noise(7, hp.humidity_noise_pct), 0.0, 100.0),
            "depth_m": depth,
            "pressure_dbar": depth * DBAR_PER_M,
        }

    def sensor_sample(self, module: str, t_s: float) -> SensorSample:
        """The latest sensor sample of a module at or before dive time ``t_s``.

        Samples sit on a grid of ``sensor_rate_hz``; the sample's ``t`` is its
        grid time. Noise is a fixed function of (seed, module, sample index).
        """
        k = self.sensor_index(t_s)
        s = self._samples(module, np.array([k], dtype=np.int64))
        acc, gyro = s["acc_m_s2"][0], s["gyro_dps"][0]
        return SensorSample(
            t=self.time_at(float(s["t_s"][0])),
            module=module,
            temperature_c=round(float(s["temperature_c"][0]), 3),
            humidity_pct=round(float(s["humidity_pct"][0]), 2),
            acc_m_s2=(float(acc[0]), float(acc[1]), float(acc[2])),
            gyro_dps=(float(gyro[0]), float(gyro[1]), float(gyro[2])),
            depth_m=round(float(s["depth_m"][0]), 3),
            pressure_dbar=round(float(s["pressure_dbar"][0]), 2),
        )

    # -- frames --------------------------------------------------------------
    def water_state(self, module: str, t_s: float) -> tuple[str, int, int]:
        """The quantised water state of a module's light path at ``t_s``: one renderer each.

        ``(module, round(w / water_weight_step), round((f - 1) / drift_step))``
        with ``w`` the column's depth weight at the path's midpoint and ``f``
        its drift factor (see `WaterColumn`).
        """
        column = self.water_column
        qw = round(column.depth_weight(self.path_depth_m(module, t_s)) / self.water_weight_step)
        qf = round((column.drift_factor(t_s) - 1.0) / self.drift_step)
        return module, qw, qf

    def _renderer(self, module: str, t_s: float, wavelength_nm: int) -> FrameRenderer:
        """The renderer for a module's quantised water state at ``t_s``, built on first use, with
        its halo at ``wavelength_nm`` ready (built here under the lock, never concurrently in render;
        only the colours a state is shot in: most states last less than one colour's block)."""
        column = self.water_column
        key = self.water_state(module, t_s)
        _, qw, qf = key
        with self._lock:
            renderer = self._renderers.get(key)
            if renderer is not None:
                self._renderers.move_to_end(key)
            else:
                water = column.water_for(min(qw * self.water_weight_step, 1.0), 1.0 + qf * self.drift_step)
                renderer = FrameRenderer(
                    self.camera,
                    self.placement(module),
                    water,
                    self.lem,
                    seed=self.seed,
                    double_image=module in self.double_image_cameras,
                )
                self._renderers[key] = renderer
                self.renderers_built += 1
                while len(self._renderers) > self._cache_size:
                    self._renderers.popitem(last=False)
            renderer.halo_table(wavelength_nm)
            return renderer

    def render(
        self,
        module: str,
        t_s: float,
        exposure_s: float,
        gain_db: float,
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, dict[str, object]]:
        """The frame a module's camera takes with an exposure starting at dive time ``t_s``.

        What it models:

        * the LEM shows ``timetable.wavelength_at(t_s)``; it glows in every
          phase (the camera decides when to shoot, see
          `DiveProfile.captures_enabled`);
        * the light crosses the water of the column at the path's midpoint
          depth (`WaterColumn`), quantised (`water_state`) so that the test
          stops and the station need a few dozen renderers at most (frames
          taken while the cable moves, where the water changes continuously,
          build a new one every few metres near the surface);
          ``lambda_att_m`` in the result is the value rendered,
          ``lambda_att_column_m`` the exact column value;
        * the LEM sits where the module's attitude and sway put it at
          mid-exposure (`ModuleMotion.pointing_offset_px`) and is smeared
          along its track during the exposure (`ModuleMotion.blur_px`).

        Without ``rng`` the frame's noise is drawn from (seed, module, t_s),
        so asking again gives the same frame.

        Returns the 8-bit frame and a dict of truth and metadata: the
        renderer's `FrameTruth` fields plus ``module``, ``t_s``,
        ``captured_at`` (ISO UTC), ``phase``, ``captures_enabled``,
        ``depth_m`` (the module's), ``lem_depth_m``, ``water_depth_m``,
        ``lambda_att_column_m``, ``lambda_abs_m``, ``lambda_sca_m``,
        ``tilt_deg``, ``tilt_x_deg``, ``tilt_y_deg``, ``heading_deg``,
        ``offset_px``, ``blur_xy_px``, ``focal_px``, ``frame_scale``,
        ``lem_changed_during_exposure`` and ``timetable``.
        """
        placement = self.placement(module)
        motion = self.motions[module]
        wavelength = self.timetable.wavelength_at(t_s)
        renderer = self._renderer(module, t_s, wavelength)
        focal = self.camera.focal_px
        mid = t_s + exposure_s / 2.0
        offset = motion.pointing_offset_px(mid, focal, placement.distance_m)
        blur = motion.blur_px(t_s, exposure_s, focal, placement.distance_m)
        if rng is None:
            t_us = round(t_s * 1e6) % (2**63)
            rng = np.random.default_rng([self.seed % (2**63), stable_key("frame", module), t_us])
        frame, truth = renderer.render(
            wavelength,
            exposure_s,
            gain_db,
            rng=rng,
            offset_px=offset,
            blur_px=blur,
            lem_on=True,
            flashes_per_frame=self.flashes_per_frame,
        )
        attitude = motion.attitude_at(mid)
        optics = renderer.water.at(wavelength)
        meta: dict[str, object] = truth.to_dict()
        meta.update(
            module=module,
            t_s=float(t_s),
            captured_at=self.time_at(t_s).isoformat().replace("+00:00", "Z"),
            phase=self.profile.phase_at(t_s),
            captures_enabled=self.profile.captures_enabled(t_s),
            depth_m=self.module_depth_m(module, t_s),
            lem_depth_m=self.profile.lem_depth_at(t_s),
            water_depth_m=self.path_depth_m(module, t_s),
            lambda_att_column_m=self.lambda_att_truth_m(module, wavelength, t_s),
            lambda_abs_m=optics.lambda_abs_m,
            lambda_sca_m=optics.lambda_sca_m,
            tilt_deg=attitude.tilt_deg,
            tilt_x_deg=attitude.tilt_x_deg,
            tilt_y_deg=attitude.tilt_y_deg,
            heading_deg=attitude.heading_deg,
            offset_px=offset,
            blur_xy_px=blur,
            focal_px=focal,
            frame_scale=self.frame_scale,
            lem_changed_during_exposure=self.timetable.next_change_after(t_s) < t_s + exposure_s,
            timetable=self.timetable.describe(),
        )
        return frame, meta
