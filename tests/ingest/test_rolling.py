"""The per-visit λ_att series: visits cut from frames in any arrival order, provisional then final."""

from __future__ import annotations

import dataclasses
import math
import random

import pytest

from camcal.core.frameset import SeriesSetup, Setup
from ingest.rolling import Sample, VisitSeries, series_rows

SETTINGS = ((0.05, 8.0), (0.07, 8.0), (0.11, 8.0))
LAMBDA = {405: 20.0, 460: 28.0, 525: 21.0}
RATIO = {405: 1.04, 460: 1.27, 525: 1.23}
T0 = 1.7e9


def block(k: int, wl: int, t0: float, *, n: int = 6, first_id: int = 0, cams=("A", "B")) -> list[Sample]:
    """A visit's frames: each camera takes the settings in turn, one frame a second, B 0.45 s later."""
    out = []
    fid = first_id
    for c, cam in enumerate(cams):
        dist = 21.56 if cam == "A" else 41.62
        for i in range(n):
            e, g = SETTINGS[i % 3]
            t = t0 + i + 0.45 * c
            i_gray = (
                3e5
                * e
                * 10 ** (g / 20)
                * (RATIO[wl] if cam == "B" else 1)
                * math.exp(-dist / LAMBDA[wl])
                / 100
            )
            i_gray *= 1 + 0.002 * math.sin(7 * fid + k)  # a little scatter, reproducible
            fid += 1
            out.append(Sample(fid, cam, wl, t, 3400.0 - dist, e, g, True, i_gray, 0.002 * i_gray))
    return out


def timetable(n_blocks: int, dwell_s: float = 60.0) -> list[Sample]:
    """The LEM cycling 405, 460, 525 for ``dwell_s`` each; six frames per camera at each block's start."""
    out: list[Sample] = []
    for k in range(n_blocks):
        wl = (405, 460, 525)[k % 3]
        out += block(k, wl, T0 + k * dwell_s, first_id=len(out))
    return out


def test_one_point_per_visit_stamped_at_its_frames_with_the_lem_depth() -> None:
    samples = timetable(9)
    rows = series_rows(samples, Setup())
    assert [r["wavelength_nm"] for r in rows] == [405, 460, 525] * 3
    for k, r in enumerate(rows):
        visit = [s for s in samples if T0 + k * 60 <= s.t_unix_s < T0 + (k + 1) * 60]
        assert r["t_unix_s"] == pytest.approx(sum(s.t_unix_s for s in visit) / len(visit))
        assert r["depth_m"] == pytest.approx(3400.0)  # module depth + distance: the LEM's
        assert r["n_frames"] == 12 and r["n_pairs"] == 3 and r["final"]
        assert r["lambda_att_m"] == pytest.approx(LAMBDA[r["wavelength_nm"]], rel=0.01)
        assert r["t_first_unix_s"] <= r["t_unix_s"] <= r["t_last_unix_s"]


def test_a_gap_longer_than_visit_gap_s_ends_a_visit_of_one_wavelength() -> None:
    samples = block(0, 460, T0) + block(1, 460, T0 + 20, first_id=100) + block(2, 460, T0 + 100, first_id=200)
    rows = series_rows(samples, Setup(series=SeriesSetup(visit_gap_s=30.0)))
    assert [r["n_frames"] for r in rows] == [24, 12]


def test_a_visit_ends_where_the_lem_moved_to_another_depth() -> None:
    """The winch moves from a test stop to the station in 15 s, the LEM still showing 460 nm."""
    stop = block(0, 460, T0)
    station = [
        Sample(
            s.frame_id + 100,
            s.module,
            460,
            s.t_unix_s + 21,
            s.depth_m + 1399.0,
            s.exposure_s,
            s.gain_db,
            True,
            s.i_center_gray,
            s.i_center_err_gray,
        )
        for s in stop
    ]
    rows = series_rows(stop + station, Setup())
    assert [round(r["depth_m"]) for r in rows] == [3400, 4799]


def test_a_frame_set_that_gives_both_cameras_one_depth_is_not_cut_between_them() -> None:
    """Frame sets often carry one depth for the set: the two cameras then differ by their distance."""
    same = [dataclasses.replace(s, depth_m=3400.0) for s in block(0, 525, T0)]
    rows = series_rows(same, Setup())
    assert len(rows) == 1 and rows[0]["n_frames"] == 12


def test_a_long_run_of_one_wavelength_is_cut_at_multiples_of_visit_max_s() -> None:
    samples = []
    for k in range(180):  # 460 nm for 30 minutes: three frames per camera every 10 s
        samples += block(k, 460, T0 + 10 * k, n=3, first_id=10 * k)
    rows = series_rows(samples, Setup(series=SeriesSetup(visit_max_s=600.0)))
    assert T0 % 600 == 200 and len(rows) == 4  # cut at T0 + 400, + 1000, + 1600
    for r in rows:
        assert r["t_last_unix_s"] - r["t_first_unix_s"] <= 600.0
        assert math.floor(r["t_first_unix_s"] / 600) == math.floor(r["t_last_unix_s"] / 600)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_results_in_any_order_and_batching_give_the_series_of_all_at_once(seed: int) -> None:
    samples = timetable(12)
    rejected = [
        Sample(10_000 + i, "A", 405, T0 + 5.5 + 180 * i, 3378.0, 0.5, 20.0) for i in range(4)
    ]  # saturated frames: they mark visits, they carry no I
    everything = samples + rejected
    reference = series_rows(everything, Setup())
    rng = random.Random(seed)
    shuffled = everything[:]
    rng.shuffle(shuffled)
    live = VisitSeries(Setup())
    stored: dict[str, dict] = {}
    i = 0
    while i < len(shuffled):
        n = rng.randint(1, 9)
        changes = live.add(shuffled[i : i + n])
        i += n
        for key in changes.deletes:
            stored.pop(key)
        for row in changes.upserts:
            stored[row["visit_key"]] = row
    for row in live.close_all().upserts:
        stored[row["visit_key"]] = row
    got = sorted(stored.values(), key=lambda r: (r["t_unix_s"], r["wavelength_nm"]))
    assert [r["visit_key"] for r in got] == [r["visit_key"] for r in reference]
    for a, b in zip(got, reference, strict=True):
        assert a == b


def test_a_visit_is_provisional_until_both_cameras_have_moved_on() -> None:
    series = VisitSeries(Setup())
    first = block(0, 405, T0)
    changes = series.add(first)
    assert [r["final"] for r in changes.upserts] == [False]
    # Camera A moves on to 460 nm: B has not, the 405 visit stays open.
    nxt = block(1, 460, T0 + 60, first_id=100)
    changes = series.add([s for s in nxt if s.module == "A"])
    assert not [r for r in changes.upserts if r["wavelength_nm"] == 405 and r["final"]]
    changes = series.add([s for s in nxt if s.module == "B"])
    final = [r for r in changes.upserts if r["wavelength_nm"] == 405]
    assert len(final) == 1 and final[0]["final"]
    assert [r["final"] for r in changes.upserts if r["wavelength_nm"] == 460] == [False]
    assert [r["final"] for r in series.close_all().upserts] == [True]


def test_a_late_frame_updates_a_final_visit_and_a_bridging_one_joins_two() -> None:
    setup = Setup(series=SeriesSetup(visit_gap_s=30.0))
    series = VisitSeries(setup)
    a = block(0, 460, T0)
    b = block(1, 460, T0 + 50, first_id=100)
    series.add(a + b + block(2, 525, T0 + 120, first_id=200))
    keys = {r["visit_key"] for r in series.points() if r["wavelength_nm"] == 460}
    assert len(keys) == 2
    # A frame in the gap between the two 460 nm visits: they are one visit now.
    bridge = Sample(
        999, "B", 460, T0 + 30.0, 3378.0, 0.07, 8.0, True, a[-1].i_center_gray, a[-1].i_center_err_gray
    )
    changes = series.add([bridge])
    assert len(changes.deletes) == 1 and changes.deletes[0] in keys
    joined = [r for r in changes.upserts if r["wavelength_nm"] == 460]
    assert len(joined) == 1 and joined[0]["n_frames"] == 25 and joined[0]["final"]
    assert joined[0] == next(r for r in series_rows(a + b + [bridge], setup) if r["wavelength_nm"] == 460)


def test_a_setup_without_two_cameras_has_no_series() -> None:
    with pytest.raises(ValueError, match="two cameras"):
        VisitSeries(Setup(cameras={"A": {"distance_m": 21.56}}))


def test_a_module_clock_that_was_off_is_corrected_by_the_setups_clock_offset() -> None:
    """Camera B's clock 90 s ahead (a module without NTP): its frames fall among another colour's
    and no visit pairs the cameras; with B's ``clock_offset_s`` in the setup (what a re-analysis's
    ``--clock-offset B=90`` sets) the series is the one of the right times."""
    samples = timetable(9)
    ahead = [dataclasses.replace(s, t_unix_s=s.t_unix_s + 90.0) if s.module == "B" else s for s in samples]
    assert series_rows(ahead, Setup()) == []
    data = Setup().model_dump()
    data["cameras"]["B"]["clock_offset_s"] = 90.0
    repaired = series_rows(ahead, Setup.model_validate(data))
    right = series_rows(samples, Setup())
    assert len(repaired) == len(right) == 9
    for r, ok in zip(repaired, right, strict=True):
        assert r["lambda_att_m"] == pytest.approx(ok["lambda_att_m"], rel=1e-12)
        assert r["t_unix_s"] == pytest.approx(ok["t_unix_s"], abs=1e-6)  # stamped on the true time


def test_a_clock_days_behind_is_repaired_too() -> None:
    """A Raspberry Pi whose clock came back at its last shutdown's time (fake-hwclock, no battery)
    runs days behind: the setup takes such an offset (it took at most a day before)."""
    behind_s = -3 * 86400.0 - 17.0
    samples = timetable(9)
    late = [dataclasses.replace(s, t_unix_s=s.t_unix_s + behind_s) if s.module == "B" else s for s in samples]
    data = Setup().model_dump()
    data["cameras"]["B"]["clock_offset_s"] = behind_s
    repaired = series_rows(late, Setup.model_validate(data))
    assert len(repaired) == len(series_rows(samples, Setup())) == 9
