"""The dive report: one self-contained HTML file of a stored dive (``camcal report``)."""

from __future__ import annotations

from pathlib import Path

from camcal.core.files import write_atomic
from camcal.report.collect import ReportData, collect
from camcal.report.render import SECTIONS, render
from storage.store import Store


def write_report(store: Store, dive_name: str, out: Path, run_id: int | None = None) -> ReportData:
    """Collect a dive's results from the store and write its report to ``out`` (atomically)."""
    data = collect(store, dive_name, run_id)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, render(data).encode("utf-8"), fsync=False)
    return data


__all__ = ["SECTIONS", "ReportData", "collect", "render", "write_report"]
