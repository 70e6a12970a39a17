"""bench/qos.py's loss split and run merging on hand-made captures: a high frame missing at the
capture is lost after the bridge only if a sequence number the bridge gave is missing (else the
bus never delivered it); a frame read just before the router stop and delivered after it is one
the stop caught; several runs of a variant are one row (counts summed, figures the median)."""
from __future__ import annotations

import pytest

from bench import qos
from canbench import wire

pytestmark = pytest.mark.unit


def capture_line(t_ns: int, first_seq: int, frames: list[tuple[int, int]]) -> str:
    """A zn-capture TSV line of one sample: frames (CAN id, send stamp), CAN stamps = t_ns - 1."""
    payload = b"".join(wire.encode(wire.Frame(can_id=i, dlc=8, data=s.to_bytes(8, "little"))) for i, s in frames)
    att = wire.encode_attachment(first_seq, [t_ns - 1] * len(frames))
    return f"{t_ns}\tvehicle/can/rx\t{payload.hex().upper()}\t{att.hex().upper()}\n"


def test_a_lost_frame_with_no_number_missing_was_never_read_by_the_bridge(tmp_path):
    tsv = tmp_path / "zenoh.tsv"
    # the bridge read 5 frames (0..4), numbers 0..4 all captured, a batch of two among them
    tsv.write_text(capture_line(10, 0, [(0x10, 1)]) + capture_line(20, 1, [(0x600, 2), (0x600, 3)])
                   + capture_line(30, 3, [(0x10, 4)]) + capture_line(40, 4, [(0x600, 5)]))
    seqs = qos.sequence_numbers(tsv)
    assert seqs == {0, 1, 2, 3, 4}
    split = qos.split_loss(lost=2, numbered=5, seqs=seqs)
    assert split == {"lost_after_bridge_read_all_ids": 0, "lost_after_bridge_read_at_most": 0,
                     "lost_before_bridge_at_least": 2}


def test_numbers_missing_bound_the_loss_after_the_bridge_in_flight_ones_included():
    # 10 read; 3 and 9 missing (9: still in flight when the capture was read)
    split = qos.split_loss(lost=1, numbered=10, seqs={0, 1, 2, 4, 5, 6, 7, 8})
    assert split == {"lost_after_bridge_read_all_ids": 2, "lost_after_bridge_read_at_most": 1,
                     "lost_before_bridge_at_least": 0}
    assert qos.split_loss(lost=5, numbered=10, seqs=set(range(9)))["lost_before_bridge_at_least"] == 4


def test_a_frame_read_before_the_stop_and_delivered_after_it_was_caught_by_it():
    window = [1000, 2000]
    frames = [(500, 900),    # read and delivered before the stop: moved
              (990, 2100),   # read just before, delivered after: waited through the stop
              (1500, 2050),  # read during the stop
              (2010, 2300)]  # read after it: behind the backlog or past it
    assert qos.not_caught_by_stop(frames, window) == [(500, 900), (2010, 2300)]
    assert qos.not_caught_by_stop(frames, []) == frames


def run(lost, p50, p99, after=0):
    return {"variant": "flood, table", "table": "t", "sent": 1500, "received": 1500 - lost, "lost": lost,
            "lost_after_bridge_read_all_ids": after, "lost_after_bridge_read_at_most": min(lost, after),
            "lost_before_bridge_at_least": lost - min(lost, after), "p50_us": p50, "p99_us": p99,
            "high_fps": 500, "pause_s": 0.5, "from_can_stamp_outside_stop": {"p50_us": p50 / 10, "p99_us": p99 / 10},
            "flood": {"sent": 36000, "received": 35900, "delivered_fps": 7000}, "rx_queue_drops": 0}


def test_runs_of_a_variant_are_one_row_counts_summed_figures_the_median():
    row = qos.combine([run(9, 16000, 90000), run(0, 9000, 30000), run(1, 8000, 20000, after=1)])
    assert row["lost"] == 10 and row["sent"] == 4500 and row["lost_before_bridge_at_least"] == 9
    assert row["lost_after_bridge_read_at_most"] == 1
    assert row["p50_us"] == 9000 and row["p99_us"] == 30000
    assert row["from_can_stamp_outside_stop"] == {"p50_us": 900, "p99_us": 3000}
    assert row["flood"] == {"sent": 108000, "received": 107700, "delivered_fps": 7000}
    assert row["pause_s"] == 0.5 and row["variant"] == "flood, table" and len(row["runs"]) == 3
    md = qos.table_md([row], [], {})
    assert "| 10 / 1 / 9 |" in md and "Median of 3 runs" in md
    assert "- flood, table: 1600.0 / 9000.0 (9, 0); 900.0 / 3000.0 (0, 0); 800.0 / 2000.0 (1, 1)" in md


def test_variants_are_named_with_colons_for_their_commas():
    assert qos.chosen_variants("flood:table, reliable:block") == {"flood, table", "reliable, block"}
    assert qos.chosen_variants(None) == set()
    with pytest.raises(SystemExit, match="unknown flood, tabel"):
        qos.chosen_variants("flood:tabel")
