"""Sequence tracking: duplicates, order, gaps from jumps and from what a lost module said it had."""

from __future__ import annotations

from ingest.seqtrack import SeqTracker


def test_a_jump_opens_a_gap_and_resends_fill_it() -> None:
    t = SeqTracker()
    assert [t.add("A", "b", q) for q in (1, 2)] == [None, None]
    assert t.add("A", "b", 6) == (3, 5)
    assert t.missing("A", "b") == [(3, 5)]
    assert t.add("A", "b", 4) is None and t.add("A", "b", 2) is None  # a resend, a duplicate
    assert t.missing("A", "b") == [(3, 3), (5, 5)]
    t.add("A", "b", 3)
    t.add("A", "b", 5)
    assert t.missing("A", "b") == [] and t.arrived("A", "b") == {1, 2, 3, 4, 5, 6}


def test_expect_opens_a_gap_for_what_the_module_produced_and_the_ship_lacks() -> None:
    t = SeqTracker()
    t.seed("A", "b", {1, 2, 3})
    assert t.expect("A", "b", 3) is None  # nothing outstanding
    assert t.expect("A", "b", 7) == (4, 7)
    assert t.expect("A", "b", 7) is None  # said twice: one gap
    assert t.missing("A", "b") == [(4, 7)]
    # The resends after a reconnect arrive in order: no second gap, and they fill this one.
    assert [t.add("A", "b", q) for q in (4, 5, 6, 7, 8)] == [None] * 5
    assert t.missing("A", "b") == []
    assert t.expect("B", "b", 2) == (1, 2)  # a module the ship has heard of only in heartbeats
