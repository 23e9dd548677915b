"""LEM visits on station, rendered and analysed in memory: for studies of the λ_att series.

What the live path does with two modules and the ingest, without the
processes: both cameras shoot a schedule's settings at the start of every
block of the LEM's timetable (the far camera ``interleave_s`` later, so the
frames alternate), each frame is rendered by the dive simulation and
analysed by `analysis.analyze_frame`. The result rows have the keys of
`storage.store.Store.result_rows`, so `ingest.rolling` takes them as it
takes stored results. Used by ``bench/repeatability.py`` and the tests.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

from analysis import FrameConfig, analyze_frame
from lrm.dive.simulation import DiveSimulation


def station_results(
    sim: DiveSimulation,
    settings: Sequence[tuple[float, float]],
    repeats: int,
    *,
    t_from_s: float,
    t_to_s: float,
    cameras: Sequence[str] = ("A", "B"),
    interleave_s: float = 0.45,
    readout_s: float = 0.8,
    config: FrameConfig | None = None,
) -> Iterator[list[dict[str, Any]]]:
    """Per block of the LEM's timetable in [t_from_s, t_to_s): the analysed frames of both cameras.

    Each camera takes every setting ``repeats`` times, one frame every
    exposure + ``readout_s``, starting at the block's start (camera ``k``
    ``k * interleave_s`` later). Blocks too short for the shots are skipped.
    """
    tt = sim.timetable
    epoch = sim.start.timestamp()
    shots_s = sum((e + readout_s) * repeats for e, _ in settings)
    k = math.ceil((t_from_s - tt.start_s) / tt.dwell_s)
    frame_id = 0
    while True:
        t_block = tt.start_s + k * tt.dwell_s
        k += 1
        if t_block + shots_s + interleave_s * len(cameras) > min(t_to_s, t_block + tt.dwell_s):
            if t_block >= t_to_s:
                return
            continue
        rows = []
        for i, cam in enumerate(cameras):
            t = t_block + 0.001 + i * interleave_s
            for exposure_s, gain_db in settings:
                for _ in range(repeats):
                    frame, meta = sim.render(cam, t, exposure_s, gain_db)
                    res = analyze_frame(frame, config)
                    frame_id += 1
                    rows.append(
                        {
                            "frame_id": frame_id,
                            "module": cam,
                            "wavelength_nm": int(meta["wavelength_nm"]),  # type: ignore[call-overload]
                            "exposure_s": exposure_s,
                            "gain_db": gain_db,
                            "captured_unix_s": epoch + t,
                            "depth_m": meta["depth_m"],
                            "status": res.status,
                            "reason": res.reason,
                            "center_gray": res.center_gray,
                            "i_center_gray": res.i_center_gray,
                            "i_center_err_gray": res.i_center_err_gray,
                        }
                    )
                    t += exposure_s + readout_s
        yield rows
