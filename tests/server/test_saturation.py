"""Saturated frames the schedule's design predicts are told apart from unexpected ones.

The prediction is the schedule preview's (`ingest.derived.predict_settings`): from the frames in
the linear range, the LEM's brightness per unit of exposure and gain. Frames of a sweep's long
exposures are saturated by design; a frame saturated at a setting predicted well inside the linear
range is not, and is what the deck must see in red.
"""

from __future__ import annotations

from typing import Any

from server.saturation import quality_split, saturated_by_design, setting_key

LINEAR = (5.0, 240.0)


def row(
    module: str, exposure_s: float, center_gray: float, status: str = "ok", gain_db: float = 6.0
) -> dict[str, Any]:
    return {
        "module": module,
        "wavelength_nm": 460,
        "exposure_s": exposure_s,
        "gain_db": gain_db,
        "captured_unix_s": 0.0,
        "depth_m": 3420.0,
        "status": status,
        "center_gray": center_gray,
        "i_center_gray": None if status != "ok" else center_gray - 3.0,
        "i_center_err_gray": 0.1,
    }


def test_a_sweeps_long_exposures_are_saturated_by_design_and_a_short_one_is_not() -> None:
    # ~1000 gray per second at 6 dB above a dark level of 3: 0.05 s gives ~53, 0.5 s ~500 (clipped)
    rows = [row("A", 0.02, 23.0), row("A", 0.05, 53.0), row("A", 0.11, 113.0)] * 3
    rows += [row("A", 0.5, 255.0, "rejected"), row("A", 1.0, 255.0, "rejected")]
    rows += [row("A", 0.05, 255.0, "rejected")]  # saturated where ~53 gray was expected: unexpected
    design = saturated_by_design(rows, LINEAR)
    assert design["A"] == {setting_key(460, 0.5, 6.0), setting_key(460, 1.0, 6.0)}
    assert setting_key(460, 0.05, 6.0) not in design["A"]

    counted = {(460, 0.5, 6.0): 1, (460, 1.0, 6.0): 1, (460, 0.05, 6.0): 1}
    split = quality_split({"ok": 9, "saturated": 3}, counted, design["A"])
    assert split == {"ok": 9, "saturated_by_design": 2, "saturated": 1}


def test_without_a_usable_frame_at_a_wavelength_nothing_is_saturated_by_design() -> None:
    """Every frame of a wavelength saturated: the prediction knows nothing, so none is 'expected'
    (the whole wavelength lost is a fault, and the alarm says so)."""
    rows = [row("B", e, 255.0, "rejected") for e in (0.02, 0.05, 0.11)]
    assert not saturated_by_design(rows, LINEAR).get("B")
    assert quality_split({"saturated": 3}, {(460, 0.02, 6.0): 3}, frozenset()) == {"saturated": 3}
