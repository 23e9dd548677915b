"""When the store thread stores the analysis results that came back (`ingest.storeloop.results_due`)."""

from __future__ import annotations

from ingest.storeloop import RESULT_BATCH, RESULT_HOLD_S, results_due


def test_a_result_with_nothing_else_running_is_stored_at_once() -> None:
    """At a module's pace (one frame at a time) a result never waits."""
    assert results_due(1, 0.0, busy=False)
    assert not results_due(0, 10.0, busy=False)  # nothing to store


def test_results_wait_for_others_while_analyses_run_up_to_a_batch_or_a_time() -> None:
    """At full speed results gather into one transaction: a batch, or the oldest's hold time."""
    assert not results_due(1, 0.0, busy=True)
    assert not results_due(RESULT_BATCH - 1, RESULT_HOLD_S * 0.9, busy=True)
    assert results_due(RESULT_BATCH, 0.0, busy=True)
    assert results_due(1, RESULT_HOLD_S, busy=True)
    assert 1 < RESULT_BATCH <= 64 and 0 < RESULT_HOLD_S <= 0.5  # a hold well inside the 0.5 s result aim
