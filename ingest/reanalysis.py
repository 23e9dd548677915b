"""Re-analysing a stored dive with other calibration inputs, beside the original results."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from analysis import FrameConfig
from camcal import __version__
from camcal.frameset import Setup
from ingest.derived import ResultRow, geometry_and_ratios, linearity_rows, mean_gray_by_setting
from ingest.importer import analyse_frames
from ingest.rolling import RollingAttenuation, Sample
from storage.store import Store

log = logging.getLogger("camcal.reanalysis")


@dataclass(frozen=True)
class ReanalysisOptions:
    window_s: float = 300.0
    interval_s: float = 10.0
    workers: int = 1


def start_run(
    store: Store, dive_id: int, setup: Setup, label: str = "", calibration_id: int | None = None
) -> int:
    run = store.analysis_run(
        dive_id,
        "reanalysis",
        label=label,
        calibration=setup.to_json(),
        calibration_id=calibration_id,
        software_version=__version__,
    )
    assert run is not None
    return run.id


def reanalyse(
    store: Store,
    dive_id: int,
    run_id: int,
    setup: Setup,
    options: ReanalysisOptions | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> int:
    """Fill run ``run_id`` of a dive: frame results, the λ_att series and linearity.

    When the linear range is the live run's, each frame's I_center is
    unchanged and its result is copied; otherwise every frame is analysed
    again. Distances and emission ratios only enter λ_att, which is always
    recomputed. The live run is never touched. Returns the number of frames.
    """
    options = options or ReanalysisOptions()
    live = store.analysis_run(dive_id, "live", create=False)
    try:
        same_range = live is not None and tuple(live.calibration.get("linear_range", ())) == tuple(
            setup.linear_range
        )
        if progress:
            progress("frames", 0.0)
        if same_range and live is not None:
            n = store.copy_results(live.id, run_id)
        else:
            frames = store.dive_frames(dive_id)
            lo, hi = setup.linear_range
            n = analyse_frames(
                store, run_id, frames, workers=options.workers, config=FrameConfig(linear_range_gray=(lo, hi))
            )
        if progress:
            progress("attenuation", 0.7)
        rows = store.result_rows(run_id, dive_id)
        gr = geometry_and_ratios(setup)
        points = []
        if gr is not None:
            rolling = RollingAttenuation(gr[0], gr[1], options.window_s, options.interval_s)
            for r in rows:
                if r["status"] != "ok" or r["i_center_gray"] is None:
                    continue
                out = rolling.add(
                    r["module"],
                    r["wavelength_nm"],
                    r["exposure_s"],
                    r["gain_db"],
                    Sample(r["captured_unix_s"], r["i_center_gray"], r["i_center_err_gray"], r["depth_m"]),
                )
                if out is not None:
                    res, t, depth = out
                    points.append(
                        {
                            "run_id": run_id,
                            "dive_id": dive_id,
                            "wavelength_nm": res.wavelength_nm,
                            "t_unix_s": t,
                            "depth_m": depth,
                            "lambda_att_m": res.lambda_att_m,
                            "stat_err_m": res.stat_err_m,
                            "sys_err_m": res.sys_err_m,
                            "n_pairs": res.n_pairs,
                            "chi2_ndof": res.chi2_ndof,
                            "window_s": options.window_s,
                            "details": {"note": res.note},
                        }
                    )
        store.add_attenuation_points(points)
        result_rows = [
            ResultRow(
                r["module"],
                r["wavelength_nm"],
                r["exposure_s"],
                r["gain_db"],
                r["captured_unix_s"],
                r["depth_m"],
                r["status"],
                r["center_gray"],
                r["i_center_gray"],
                r["i_center_err_gray"],
            )
            for r in rows
        ]
        lr = tuple(setup.linear_range)
        for (module, wl), pts in mean_gray_by_setting(result_rows).items():
            for row in linearity_rows(pts, lr):  # type: ignore[arg-type]
                import time

                store.upsert_linearity(
                    {
                        **row,
                        "run_id": run_id,
                        "module_id": module,
                        "wavelength_nm": wl,
                        "updated_unix_s": time.time(),
                    }
                )
        store.finish_run(run_id, "done", n)
        if progress:
            progress("done", 1.0)
        return n
    except Exception:
        log.exception("re-analysis %s of dive %s failed", run_id, dive_id)
        store.finish_run(run_id, "failed")
        raise
