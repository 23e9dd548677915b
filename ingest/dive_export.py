"""A dive's export as a scientist takes it away: its tables (`storage.export`) and the λ_att per
wavelength the review page and the report show (over the station: the deepest 50 m), so that a
number on the page can be found in the files. One use case for the CLI and the server."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ingest.spans import attenuation_dict, attenuation_over_span
from storage import queries
from storage.export import FORMATS, export_dive
from storage.store import Store


def station_rows(store: Store, dive_id: int, run_id: int) -> list[dict[str, Any]]:
    """λ_att per wavelength of a run over the station, one row each with its span and errors."""
    with store.read() as s:
        run = queries.chosen_run(s, dive_id, run_id)
        setup = queries.setup_in_force(s, dive_id, run)
        rows = queries.result_rows(s, run_id, dive_id)
    span, table = attenuation_over_span(rows, setup)
    out = []
    for wl in sorted(table.overall):
        row = {k: v for k, v in attenuation_dict(table.overall[wl]).items() if k != "pairs"}
        out.append(
            {
                "run_id": run_id,
                **row,
                "span_depth_min_m": span["depth_min_m"],
                "span_depth_max_m": span["depth_max_m"],
                "span_n_frames": span["n_frames"],
            }
        )
    return out


def export_dive_with_results(
    store: Store, dive_id: int, out: Path, formats: tuple[str, ...] = FORMATS, run_id: int | None = None
) -> list[Path]:
    """`storage.export.export_dive`, with ``lambda_att`` (`station_rows`) when a run is exported."""
    extra = {"lambda_att": station_rows(store, dive_id, run_id)} if run_id is not None else None
    return export_dive(store, dive_id, out, formats, run_id, extra)
