"""What the camera looks at: the water, the LEM and where each camera hangs."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from analysis.scattering import WaterOptics

WAVELENGTHS_NM: tuple[int, ...] = (405, 460, 525)


@dataclass(frozen=True)
class Water:
    """Optical properties per wavelength (nm -> `WaterOptics`)."""

    optics: Mapping[int, WaterOptics]
    name: str = "custom"

    def at(self, wavelength_nm: int) -> WaterOptics:
        try:
            return self.optics[int(wavelength_nm)]
        except KeyError:
            known = ", ".join(str(w) for w in sorted(self.optics))
            raise ValueError(f"no water optics for {wavelength_nm} nm (known: {known})") from None

    def lambda_att_m(self) -> dict[int, float]:
        return {wl: o.lambda_att_m for wl, o in sorted(self.optics.items())}


def _water(name: str, values: dict[int, tuple[float, float]]) -> Water:
    return Water({wl: WaterOptics(a, s) for wl, (a, s) in values.items()}, name=name)


#: (absorption, scattering) lengths in metres per wavelength.
#: ``trex``: deep West-Pacific water from TRIDENT's Geant4 configuration
#: (attenuation 20 / 28 / 21 m); ``clear``: ~55 m attenuation; ``turbid``: ~12 m.
WATER_PRESETS: dict[str, dict[int, tuple[float, float]]] = {
    "trex": {405: (39.0, 39.0), 460: (65.0, 50.0), 525: (31.0, 65.0)},
    "clear": {405: (90.0, 120.0), 460: (100.0, 140.0), 525: (80.0, 160.0)},
    "turbid": {405: (22.0, 25.0), 460: (25.0, 25.0), 525: (20.0, 30.0)},
}


def water_preset(name: str) -> Water:
    """One of the named waters in `WATER_PRESETS`."""
    try:
        return _water(name, WATER_PRESETS[name])
    except KeyError:
        raise ValueError(f"unknown water {name!r}; choose from {', '.join(WATER_PRESETS)}") from None


@dataclass(frozen=True)
class LEMModel:
    """The light emitter module: a glowing 0.43 m sphere.

    ``radiance_e_per_s`` is the surface radiance of the side facing the near
    camera, as electrons per second in one pixel at 0 dB before any water.
    ``emission_ratio`` is the true I0'/I0 (far side over near side): the
    values the lab calibrates (1.04, 1.27, 1.23 for T-REX).
    """

    diameter_m: float = 0.43
    radiance_e_per_s: Mapping[int, float] = field(
        default_factory=lambda: {405: 40000.0, 460: 65000.0, 525: 60000.0}
    )
    emission_ratio: Mapping[int, float] = field(default_factory=lambda: {405: 1.04, 460: 1.27, 525: 1.23})

    @property
    def radius_m(self) -> float:
        return self.diameter_m / 2.0


@dataclass(frozen=True)
class Placement:
    """A camera on the cable: its id, its distance to the LEM and which side it faces."""

    camera: str
    distance_m: float
    distance_err_m: float = 0.0
    faces_far_side: bool = False

    def __post_init__(self) -> None:
        if not self.distance_m > 0:
            raise ValueError(f"distance_m of camera {self.camera} must be > 0, got {self.distance_m}")


#: The T-REX geometry: LRM-A 21.56 ± 0.02 m, LRM-B 41.62 ± 0.04 m from the LEM.
TREX_PLACEMENTS = (
    Placement("A", 21.56, 0.02, faces_far_side=False),
    Placement("B", 41.62, 0.04, faces_far_side=True),
)
