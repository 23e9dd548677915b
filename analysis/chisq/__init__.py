"""λ_abs and λ_sca from the radial profiles of both cameras: the paper's χ² method.

Data
----
Per setting (wavelength, exposure, gain) with stacked frames of both cameras:
the band means of the stacked crops (`analysis.stack.StackResult`) minus
their fitted background, both divided by the near camera's Σ G_i (the sum of
the background-subtracted gray values over the fitted region), so that the
far/near brightness ratio survives the normalisation.

Model
-----
T = direct disk + scattered-light halo for each camera. The disk
(`analysis.transport.disk`) has radiance exp(-s/λ_att) toward the near
camera and (I0'/I0)·exp(-s/λ_att) toward the far one (s the path along each
pixel's ray to the sphere's surface, L - a at the centre) and is blurred by a
Gaussian PSF; the halo comes from the transport templates
(`analysis.transport.templates`), weighted by the same emission profile.
T is normalised like the data, by its own near-camera sum.

χ²
--
::

    χ² = Σ_i [M_i - s·T_i(ε) - β_c]² / (σ_Mi² + σ_Ti²) + Σ_k ε_k² / σ_k²

The paper writes the nuisance terms as T_i(1 + Σ ε_k); here each nuisance
acts on the bins it physically changes, linearised: T_i(ε) = T_i + Σ_k ε_k
∂T_i/∂ε_k. The nuisances are the two distances, I0'/I0 (the far camera's
disk and both halos' far-side light), the PSF width (the disk's edge), the
image scale (focal length: the disk's radius and the halo's radial scale)
and the halo's overall level (the templates' own accuracy, ±0.5 %).
Per setting, a scale s (≈ 1: it takes up the normalisation's own error) and a
constant β per camera are free: the exponential + constant background fit
takes part of the faint, nearly flat wide-angle halo for background (half a
gray value in the T-REX demo frames), and β gives it back instead of biasing
λ_sca. All these enter linearly and are solved exactly at every (λ_abs,
λ_sca) (profiled). σ_T is the templates' Monte Carlo error plus a relative
model uncertainty.

The minimum over (λ_abs, λ_sca) gives the estimates; one-parameter errors are
where the profiled χ² rises by 1, the joint 68 % region where it rises by
2.30 — each times s² = χ²/ndof when that exceeds 1 (the errors scaled for a
model that does not describe the data within their errors, and said so). A
length whose interval is open on one side is a one-sided 95 % limit, never a
value (`analysis.chisq.limits`). `analysis.chisq.systematics` varies, one at
a time, what the fit holds fixed (⟨cos θ⟩, the Rayleigh share, the LEM's
angular emission shape) and reports the shifts.

Modules: ``data`` (the input profiles), ``model`` (the profiled χ²),
``fit`` (the searches), ``limits`` (values or limits), ``wavelength``
(`fit_wavelength`), ``systematics`` (the budget), ``results`` (what is
returned).
"""

from __future__ import annotations

from analysis.chisq.data import (
    FitInputError,
    ProfileData,
    SettingProfiles,
    collect_settings,
    quantisation_bias_gray,
)
from analysis.chisq.results import (
    ATT_CHECK_FLAG_SIGMA,
    DCHI2_1D,
    DCHI2_2D_68,
    DCHI2_2D_95,
    DCHI2_LIMIT_95,
    LOWER_LIMIT,
    MEASURED,
    NUISANCE_FLAG_SIGMA,
    UNCONSTRAINED,
    UPPER_LIMIT,
    ChiSquareFit,
    ContourMap,
    Estimate,
    FitConfig,
    Nuisance,
    SettingModel,
    SystematicBudget,
    SystematicShift,
)
from analysis.chisq.wavelength import fit_wavelength

__all__ = [
    "ATT_CHECK_FLAG_SIGMA",
    "DCHI2_1D",
    "DCHI2_2D_68",
    "DCHI2_2D_95",
    "DCHI2_LIMIT_95",
    "LOWER_LIMIT",
    "MEASURED",
    "NUISANCE_FLAG_SIGMA",
    "UNCONSTRAINED",
    "UPPER_LIMIT",
    "ChiSquareFit",
    "ContourMap",
    "Estimate",
    "FitConfig",
    "FitInputError",
    "Nuisance",
    "ProfileData",
    "SettingModel",
    "SettingProfiles",
    "SystematicBudget",
    "SystematicShift",
    "collect_settings",
    "fit_wavelength",
    "quantisation_bias_gray",
]
