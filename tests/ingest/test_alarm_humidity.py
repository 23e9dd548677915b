"""The housing-humidity leak alarm: a rise, not the sensor's noise.

The rise was the difference of a window's two end samples: with the housing sensor's 0.2 % of
noise (as the simulator draws it, `lrm/dive/housing.py`), a flat humidity in a one-minute window
read 0.3 %/min of noise on the rise, and the 0.5 %/min MAJOR "possible leak" came now and then
(seen at `make run`'s start, cleared a second later). It is now the least-squares slope.
"""

from __future__ import annotations

import numpy as np

from ingest.alarms import AlarmEvaluator


def _leak_alarms(humidity: np.ndarray, t_s: np.ndarray) -> list[str]:
    ev = AlarmEvaluator()
    raised = []
    for t, h in zip(t_s, humidity, strict=True):
        ev.observe_humidity("A", float(t), float(h))
        cond = ev.evaluate(float(t)).get("humidity:A")
        if cond is not None:
            raised.append(cond.message)
    return raised


def test_a_sealed_housings_noise_raises_no_leak_alarm() -> None:
    """100 module starts, 3 min each of a flat 30 % read with 0.2 % of noise every 2 s: the two-end
    rule raised the MAJOR alarm at 19 of 200 such starts (its first minutes, when the window holds
    one minute); the slope at none."""
    t = np.arange(0.0, 180.0, 2.0)
    starts = [30.0 + np.random.default_rng(seed).normal(0.0, 0.2, t.size) for seed in range(100)]
    raised = [seed for seed, flat in enumerate(starts) if _leak_alarms(flat, t)]
    assert raised == [], raised


def test_a_real_rise_still_raises_it() -> None:
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 300.0, 2.0)
    rising = 30.0 + 1.0 * t / 60.0 + rng.normal(0.0, 0.2, t.size)  # 1 %/min: a leak
    raised = _leak_alarms(rising, t)
    assert raised and "rising" in raised[-1] and "possible leak" in raised[-1], raised
