"""The saturated / too dark frames alarms: a wavelength with no usable frame, not a sweep's share.

The rule was "80 % of the module's last 60 frames saturated". The default schedule sweeps exposures
and gains and saturates ~60-85 % of the near camera's frames by design, so at `make run` the MINOR
alarm was raised and cleared five times in two minutes, telling the night crew to shorten exposures
that were right. What stops λ_att is a wavelength none of whose recent frames is usable.
"""

from __future__ import annotations

from ingest.alarms import AlarmEvaluator

SIZE = (1224, 1024)


def _frame(ev: AlarmEvaluator, wl: int, outcome: str, module: str = "A") -> None:
    ok = outcome == "ok"
    ev.observe_frame(
        module, "ok" if ok else "rejected", None if ok else outcome, (612.0, 512.0), 20.0, SIZE, wl
    )


def _sweep(saturated_share: float, n: int = 56) -> list[str]:
    """One wavelength's pass of an exposure x gain sweep: the longest settings saturate."""
    k = round(saturated_share * n)
    return ["ok"] * (n - k) + ["saturated"] * k


def test_a_sweep_that_saturates_most_frames_raises_nothing() -> None:
    ev = AlarmEvaluator()
    changes, raised = 0, False
    for _ in range(6):  # six passes of three wavelengths; 82-89 % saturated per pass
        for wl, share in ((405, 0.82), (460, 0.86), (525, 0.89)):
            for outcome in _sweep(share):
                _frame(ev, wl, outcome)
                now = "frames_saturated:A" in ev.evaluate(0.0)
                changes += now != raised
                raised = now
    assert changes == 0


def test_a_wavelength_with_no_usable_frame_raises_it_names_it_and_holds_it() -> None:
    ev = AlarmEvaluator()
    for _ in range(2):
        for outcome in _sweep(0.8):
            _frame(ev, 405, outcome)
        for _ in range(30):
            _frame(ev, 460, "saturated")  # every 460 nm setting saturates
    alarm = ev.evaluate(0.0)["frames_saturated:A"]
    assert alarm.severity == "MINOR" and "460 nm" in alarm.message and "405" not in alarm.message
    assert "none of the last 60 frames" in alarm.message and "shorten exposures" in alarm.message
    for outcome in _sweep(0.8):  # other wavelengths doing well do not clear it
        _frame(ev, 525, outcome)
    assert "frames_saturated:A" in ev.evaluate(0.0)
    _frame(ev, 460, "ok")  # one usable 460 nm frame: λ_att can come from it again
    assert "frames_saturated:A" not in ev.evaluate(0.0)


def test_too_dark_frames_raise_their_own_alarm_per_module() -> None:
    ev = AlarmEvaluator()
    for _ in range(25):
        _frame(ev, 525, "too_dark", module="B")
        _frame(ev, 525, "ok", module="A")
    conditions = ev.evaluate(0.0)
    assert set(conditions) == {"frames_too_dark:B"}
    assert "525 nm" in conditions["frames_too_dark:B"].message
    assert "lengthen exposures or raise gains" in conditions["frames_too_dark:B"].message
