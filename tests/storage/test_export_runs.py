"""A dive's export holds the run it names, the λ_att the page shows, and the dive's own logs.

The export of a re-analysis held the live run's λ_att visits beside its own (filtered by dive only),
its headline λ_att per wavelength (the review page's and the report's) was in no file, and the
alarms and audit entries of every dive went into every export. On a copy of the shared simulated
dive, with a real store and real files.
"""

from __future__ import annotations

import csv
from pathlib import Path

from sqlalchemy import update

from ingest.dive_export import export_dive_with_results
from storage import queries
from storage.models import Alarm, AuditEntry
from storage.store import Store
from tests.utils.dive_store import copy_data


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_an_export_holds_its_run_its_headline_and_its_dives_logs(dive_data, tmp_path: Path) -> None:
    data = copy_data(dive_data[0], tmp_path / "data")
    store = Store.open(data, None)
    try:
        dive = store.call(queries.dives)[0]
        live = store.call(queries.live_run_id, dive["id"])
        other = store.analysis_run(dive["id"], "reanalysis", label="B at 41.70 m")
        assert other is not None and live is not None
        store.add_attenuation_points(
            [
                {
                    "run_id": other.id,
                    "dive_id": dive["id"],
                    "wavelength_nm": 460,
                    "t_unix_s": dive["last_frame_unix_s"],
                    "lambda_att_m": 99.0,
                    "n_pairs": 1,
                    "window_s": 60.0,
                }
            ]
        )
        before = dive["first_frame_unix_s"] - 86400.0  # another dive's, a day before this one began
        store.raise_alarm("tilt:Z", "tilt", "MINOR", "module Z: tilted (another dive)", "Z")
        store.audit("deck", "ack", "alarm 1", {"note": "another dive"})
        with store.session() as s:
            s.execute(update(Alarm).where(Alarm.module_id == "Z").values(raised_unix_s=before))
            s.execute(update(AuditEntry).where(AuditEntry.target == "alarm 1").values(t_unix_s=before))

        export_dive_with_results(store, dive["id"], tmp_path / "out", ("csv",), live)
        points = _rows(tmp_path / "out" / "attenuation.csv")
        assert points and {p["run_id"] for p in points} == {str(live)}  # not the re-analysis's 99 m
        headline = _rows(tmp_path / "out" / "lambda_att.csv")
        assert headline and {int(h["wavelength_nm"]) for h in headline} <= {405, 460, 525}
        for h in headline:  # the page's numbers, with their errors and the span they cover
            assert float(h["lambda_att_m"]) > 0 and float(h["stat_err_m"]) > 0 and float(h["sys_err_m"]) > 0
            assert int(h["span_n_frames"]) > 0 and h["run_id"] == str(live)
        assert all("another dive" not in a["message"] for a in _rows(tmp_path / "out" / "alarms.csv"))
        assert all("another dive" not in a["details"] for a in _rows(tmp_path / "out" / "audit_log.csv"))

        export_dive_with_results(store, dive["id"], tmp_path / "re", ("csv",), other.id)
        assert [float(p["lambda_att_m"]) for p in _rows(tmp_path / "re" / "attenuation.csv")] == [99.0]
    finally:
        store.close()
