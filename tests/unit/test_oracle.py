"""The oracle on synthetic streams: a clean copy matches exactly, and each
fault the bench exists to catch lands in its own category and names frames."""
from __future__ import annotations

from collections import Counter

import pytest

from canbench import wire
from canbench.oracle import Observed, compare, compare_commands, cycle_times, frame_key, match_subset

pytestmark = pytest.mark.unit


def stream(n: int = 50) -> list[Observed]:
    # repeated ids with rolling counters: content repeats, as in real traces
    return [Observed(wire.Frame(0x100 + i % 3, 2, bytes([i % 16, 0xAA])), 1_000_000 * i, i, line=i + 1)
            for i in range(n)]


def received(frames: list[wire.Frame], delay_ns: int = 200_000) -> list[Observed]:
    return [Observed(f, 1_000_000 * i + delay_ns, i, key="vehicle/can/rx", seq=i) for i, f in enumerate(frames)]


def test_clean_copy_matches_everything():
    sent = stream()
    c = compare(sent, received([s.frame for s in sent]))
    s = c.summary()
    counts = (s["matched"], s["lost"], s["duplicates"], s["corrupted"], s["reordered"], s["unexpected"])
    assert counts == (50, 0, 0, 0, 0, 0)
    assert s["latency"]["p50_ms"] == pytest.approx(0.2)


def test_drop_one_in_ten_is_loss_naming_the_lines():
    sent = stream()
    c = compare(sent, received([s.frame for s in sent if s.index % 10 != 9]))
    assert [o.line for o in c.lost] == [10, 20, 30, 40, 50]
    assert not c.duplicates and not c.corrupted and not c.reordered


def test_swapped_neighbours_are_reordering():
    sent = stream()
    frames = [s.frame for s in sent]
    frames[10], frames[11] = frames[11], frames[10]
    c = compare(sent, received(frames))
    assert len(c.reordered) == 1 and c.reordered[0][0].index == 10
    assert not c.lost and not c.duplicates


def test_flipped_bit_is_corruption_with_the_byte():
    sent = stream()
    frames = [s.frame for s in sent]
    f = frames[7]
    frames[7] = wire.Frame(f.can_id, f.dlc, bytes([f.data[0], f.data[1] ^ 0x10]))
    c = compare(sent, received(frames))
    assert len(c.corrupted) == 1
    s, r, diff = c.corrupted[0]
    assert s.line == 8 and diff == [1]
    assert not c.lost and not c.unexpected


def test_duplicate_frame_is_duplicate():
    sent = stream()
    frames = [s.frame for s in sent]
    frames.insert(5, frames[4])
    c = compare(sent, received(frames))
    assert len(c.duplicates) == 1 and not c.lost


def test_fixed_delay_shows_in_latency():
    sent = stream()
    c = compare(sent, received([s.frame for s in sent], delay_ns=25_000_000))
    assert c.summary()["latency"]["p50_ms"] == pytest.approx(25.0)


def test_nothing_received_is_all_lost():
    c = compare(stream(), [])
    assert len(c.lost) == 50


def test_cycle_times_per_id():
    cycles = cycle_times(stream(30))
    assert cycles["100"]["count"] == 10 and cycles["100"]["cycle_p50_ms"] == pytest.approx(3.0)


def bus_with(commands: list[Observed], ecu_frames: list[wire.Frame], extra: list[wire.Frame] = ()) -> list[Observed]:
    """A bus carrying the commands interleaved with ECU frames, then extra frames."""
    frames = []
    for i, c in enumerate(commands):
        frames.append(c.frame)
        if i < len(ecu_frames):
            frames.append(ecu_frames[i])
    frames += list(extra)
    return [Observed(f, 1_000_000 * i + 300_000, i, line=i + 1) for i, f in enumerate(frames)]


def ecu_stream(n: int = 20) -> list[wire.Frame]:
    return [wire.Frame(0x200, 1, bytes([i % 16])) for i in range(n)]


def test_commands_separate_from_ecu_traffic():
    commands = stream(20)
    ecu = ecu_stream()
    c, theirs = compare_commands(commands, bus_with(commands, ecu), Counter(frame_key(f) for f in ecu))
    assert len(c.matched) == 20 and not c.lost and not c.unexpected and not c.duplicates
    assert [o.frame for o in theirs] == ecu
    assert c.summary()["latency"]["p50_ms"] > 0


def test_command_written_twice_or_corrupted_or_invented():
    commands = stream(20)
    f = commands[3].frame
    bus = [o.frame for o in bus_with(commands, [])]
    bus[3] = wire.Frame(f.can_id, f.dlc, bytes([f.data[0], f.data[1] ^ 0x80]))  # corrupted on the way
    bus += [commands[5].frame, wire.Frame(0x7AB, 0)]                            # a duplicate, an invented frame
    observed = [Observed(fr, 1_000_000 * i + 300_000, i, line=i + 1) for i, fr in enumerate(bus)]
    c, theirs = compare_commands(commands, observed, Counter())
    assert [s.index for s, _, _ in c.corrupted] == [3] and c.corrupted[0][2] == [1]
    assert len(c.duplicates) == 1 and [o.frame.can_id for o in c.unexpected] == [0x7AB]
    assert not c.lost and theirs == []


def test_round_trip_matches_answers_among_other_traffic():
    answers = stream(10)
    traffic = [Observed(f, 5_000_000 + i, i, key="k") for i, f in
               enumerate([wire.Frame(0x555, 0)] + [a.frame for a in answers if a.index != 4])]
    c = match_subset(answers, traffic)
    assert len(c.matched) == 9 and [o.index for o in c.lost] == [4] and not c.unexpected


def test_loss_inside_a_fault_window_is_the_faults_loss_outside_is_the_bridges():
    from canbench.oracle import FAULT_LEAD_NS, FAULT_SETTLE_NS, apply_fault_windows
    sent = stream(2000)  # one frame per ms
    fault_start, fault_end = 20_000_000 + FAULT_LEAD_NS, 25_000_000 + FAULT_LEAD_NS
    shifted = [Observed(s.frame, s.t_ns + FAULT_LEAD_NS, s.index, line=s.line) for s in sent]
    # 18..26 in the window; 30 while the reconnection settles (3 ms after the first frame got through);
    # 1100 well after that: the bridge's
    late = 27 + FAULT_SETTLE_NS // 1_000_000 + 73
    kept = [s for s in shifted if not 18 <= s.index < 27 and s.index not in (30, late)]
    c = compare(shifted, [Observed(s.frame, s.t_ns + 200_000, i, key="k", seq=i) for i, s in enumerate(kept)])
    apply_fault_windows(c, [(fault_start, fault_end)])
    assert [o.index for o in c.lost] == [late]
    assert [o.index for o in c.lost_in_faults] == [*range(18, 27), 30]
    assert c.recovery_s == [0.002]  # frame 27: sent 2 ms after the end, received 0.2 ms later (ms resolution)


def test_no_frame_after_the_fault_is_no_recovery():
    from canbench.oracle import apply_fault_windows
    sent = stream(30)
    c = compare(sent, received([s.frame for s in sent[:10]]))
    apply_fault_windows(c, [(10_000_000, 12_000_000)])
    assert c.recovery_s == [None] and c.lost  # everything after the fault stays lost


def test_loss_of_repeated_contents_is_found_where_it_happened():
    # a constant status frame every third frame (as real ECUs send), counters elsewhere: with
    # "n-th copy matches n-th copy" every later status frame would shift onto its predecessor
    # and the loss would be reported at the end of the run, outside any fault window
    sent = [Observed(wire.Frame(0x200, 2, b"\x01\x02") if i % 3 == 0 else wire.Frame(0x100, 1, bytes([i % 256])),
                     1_000_000 * i, i, line=i + 1) for i in range(600)]
    window = range(100, 130)
    arrived = [s for s in sent if s.index not in window]
    c = compare(sent, [Observed(s.frame, s.t_ns + 200_000, i) for i, s in enumerate(arrived)])
    assert [o.index for o in c.lost] == list(window)
    assert not c.duplicates and not c.reordered and not c.corrupted
    assert max(c.latency_ms) == pytest.approx(0.2)


def test_a_late_copy_of_a_repeated_frame_is_still_reordering():
    sent = [Observed(wire.Frame(0x200, 1, bytes([i % 4])), 1_000_000 * i, i, line=i + 1) for i in range(40)]
    frames = [s.frame for s in sent]
    frames[20], frames[21] = frames[21], frames[20]
    c = compare(sent, received(frames))
    assert [(a.index, b.index) for a, b in c.reordered] == [(20, 21)]
    assert not c.lost and not c.duplicates


def fast_constant_and_counter(n: int = 500) -> list[Observed]:
    """A constant 0C0 every 2 ms with a counter 1A0 between: a fast frame whose copies only time
    tells apart."""
    frames = [(k * 2_000_000 + half * 1_000_000, wire.Frame(0x0C0, 2, b"\x00\x10") if not half
               else wire.Frame(0x1A0, 1, bytes([k % 256]))) for k in range(n) for half in (0, 1)]
    return [Observed(f, t, i, line=i + 1) for i, (t, f) in enumerate(frames)]


def test_a_duplicate_of_a_fast_constant_frame_is_one_duplicate():
    # published twice, 1 us apart: the second copy has no copy sent before it; it took the next
    # one (sent 2 ms later, within the stamp slack), every later 0C0 shifted onto its predecessor:
    # 399 reordered, negative latencies, and the run called a bench error for one duplicate
    sent = fast_constant_and_counter()
    got = [Observed(s.frame, s.t_ns + 300_000 + copy * 1000, 0, key="vehicle/can/rx")
           for s in sent for copy in range(2 if s.index == 200 else 1)]
    c = compare(sent, got)
    s = c.summary()
    assert (s["duplicates"], s["reordered"], s["lost"], len(c.negative)) == (1, 0, 0, 0)
    assert [r.t_ns for r in c.duplicates] == [sent[200].t_ns + 301_000]


def test_a_capture_clock_ahead_of_the_bus_is_still_negative_latency_not_duplicates():
    # every frame received 1 ms "before" it was sent (a bench's clocks apart): no frame came within
    # half a cycle of the one before it with its key, so none is a duplicate; all are early
    sent = fast_constant_and_counter()
    c = compare(sent, [Observed(o.frame, o.t_ns - 1_000_000, 0, key="vehicle/can/rx") for o in sent])
    s = c.summary()
    assert (s["duplicates"], s["lost"], s["matched"], s["reordered"]) == (0, 0, len(sent), 0)
    assert len(c.negative) == len(sent)


def constant_every(n: int, cycle_ms: float) -> list[Observed]:
    f = wire.Frame(0x0C0, 2, b"\x00\x10")
    return [Observed(f, int(k * cycle_ms * 1_000_000), k, line=k + 1) for k in range(n)]


def test_one_bus_stamp_late_by_3_ms_is_still_a_bench_error_not_a_duplicate():
    # a 5 ms constant frame, each arriving 0.5 ms after its stamp but one stamped 3 ms late (within
    # the stamp slack): it arrives 1.5 ms after the one before, not at a duplicate's pace
    sent = constant_every(100, 5)
    got = [Observed(s.frame, s.t_ns + (-3_000_000 if s.index == 50 else 500_000), 0, key="vehicle/can/rx")
           for s in sent]
    c = compare(sent, got)
    assert (c.counts["duplicates"], c.counts["lost"], c.counts["reordered"], len(c.negative)) == (0, 0, 0, 1)


def test_batched_frames_with_a_capture_clock_ahead_are_still_bench_errors():
    # two copies of a 1 ms constant frame per 2 ms sample, both at the sample's time, the capture's
    # clock 3 ms ahead: the second of a sample follows an early first one, so it is early too
    sent = constant_every(200, 1)
    got = [Observed(s.frame, s.t_ns - s.t_ns % 2_000_000 - 700_000, 0, key="vehicle/can/rx") for s in sent]
    c = compare(sent, got)
    assert (c.counts["duplicates"], c.counts["lost"]) == (0, 0) and len(c.negative) == len(sent)
