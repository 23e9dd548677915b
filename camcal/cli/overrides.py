"""The calibration options that analyze, fit and reanalyze share: distances, I0'/I0, linear range."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import typer

from camcal.cli.common import fail, parse_floats, parse_mapping

if TYPE_CHECKING:
    from camcal.pipeline import Overrides

DistanceOption = Annotated[list[str] | None, typer.Option(help="Override a camera distance: CAM=METRES.")]
DistanceErrOption = Annotated[list[str] | None, typer.Option(help="Override a distance error: CAM=METRES.")]
RatioOption = Annotated[
    list[str] | None, typer.Option(help="Override I0'/I0: NM=VALUE[:ERR], e.g. 460=1.27:0.04.")
]
LinearRangeOption = Annotated[str | None, typer.Option(help="Override the linear range: LOW,HIGH gray.")]
ClockOffsetOption = Annotated[
    list[str] | None,
    typer.Option(
        help="A module clock that was off: CAM=SECONDS it was ahead of true time (behind: negative; "
        "the ship's 'clock' alarm and `camcal doctor` say how far). Its frames are paired with the "
        "other camera's at the corrected times."
    ),
]


def parse_ratios(items: list[str] | None) -> dict[int, tuple[float, float]]:
    """``["460=1.27:0.04"]`` -> ``{460: (1.27, 0.04)}``."""
    out: dict[int, tuple[float, float]] = {}
    for item in items or []:
        key, _sep, rest = item.partition("=")
        value, _, err = rest.partition(":")
        try:
            out[int(key)] = (float(value), float(err) if err else 0.0)
        except ValueError:
            raise fail(f"--ratio: expected NM=VALUE[:ERR] such as 460=1.27:0.04, got {item!r}") from None
    return out


def parse_linear_range(text: str | None) -> tuple[float, float] | None:
    """``"5,240"`` -> ``(5.0, 240.0)``; None stays None."""
    if not text:
        return None
    vals = parse_floats(text, "--linear-range")
    if len(vals) != 2:
        raise fail("--linear-range: give LOW,HIGH, e.g. 5,240")
    return (vals[0], vals[1])


def overrides_from(
    distance: list[str] | None,
    distance_err: list[str] | None,
    ratio: list[str] | None,
    linear_range: str | None = None,
    clock_offset: list[str] | None = None,
) -> Overrides:
    """The `Overrides` the options ask for (each one exits 2 with one line if it cannot be read)."""
    from camcal.pipeline import Overrides

    return Overrides(
        distances_m=parse_mapping(distance, "--distance") or None,
        distance_errs_m=parse_mapping(distance_err, "--distance-err") or None,
        emission_ratios=parse_ratios(ratio) or None,
        linear_range=parse_linear_range(linear_range),
        clock_offsets_s=parse_mapping(clock_offset, "--clock-offset") or None,
    )
