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
    assert t.missing("A", "b") == [] and t.arrived_ranges("A", "b") == [(1, 6)]
    assert t.covers("A", "b", 2, 6) and not t.covers("A", "b", 2, 7)


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


def test_a_jump_to_the_largest_seq_is_one_range_not_a_loop() -> None:
    t = SeqTracker()
    big = 2**63 - 1
    t.add("A", "b", 1)
    assert t.add("A", "b", big) == (2, big - 1)
    assert t.missing("A", "b") == [(2, big - 1)]
    assert t.add("A", "b", big - 1) is None
    assert t.missing("A", "b") == [(2, big - 2)]
    assert not t.covers("A", "b", 2, big - 1) and t.covers("A", "b", big - 1, big)
    assert t.expect("A", "b", big) is None


def test_ranges_merge_from_any_order() -> None:
    import random

    seqs = list(range(1, 501))
    random.Random(7).shuffle(seqs)
    t = SeqTracker()
    for q in seqs[:-1]:
        t.add("A", "b", q)
    assert len(t.missing("A", "b")) <= 1
    t.add("A", "b", seqs[-1])
    assert t.arrived_ranges("A", "b") == [(1, 500)] and t.missing("A", "b") == []
