"""The benchmarks' own arithmetic on hand-made captures: stamps read back from
zn-capture TSV (batched samples too) and candump -L logs, latency percentiles,
loss and duplicates, sustained rates, and the summary table's verdicts."""
from __future__ import annotations

import statistics

import pytest

from bench import bridge as bench_bridge
from bench import paths as bench_paths
from bench import stamps

pytestmark = pytest.mark.unit

T0 = 1_795_000_000_000_000_000


def frame(can_id: int, stamp: int) -> str:
    return (can_id.to_bytes(4, "little") + bytes([8, 0, 0, 0]) + stamp.to_bytes(8, "little")).hex().upper()


def test_zenoh_stamps_reads_every_frame_of_a_batch_and_filters_by_id(tmp_path):
    tsv = tmp_path / "z.tsv"
    tsv.write_text(f"{T0 + 500_000}\tvehicle/can/rx\t{frame(0x100, T0)}{frame(0x322, T0 + 1)}\t-\n"
                   f"{T0 + 900_000}\tvehicle/can/rx\t{frame(0x100, T0 + 2)}\t01000100\n"
                   f"{T0 + 990_000}\tvehicle/can/rx\t{frame(0x100, T0 + 3)[:12]}")  # still being written
    assert stamps.zenoh_stamps(tsv) == [(T0, T0 + 500_000), (T0 + 1, T0 + 500_000), (T0 + 2, T0 + 900_000)]
    assert stamps.zenoh_stamps(tsv, 0x322) == [(T0 + 1, T0 + 500_000)]
    assert stamps.zenoh_stamps(tmp_path / "missing.tsv") == []


def test_candump_stamps_takes_the_bus_time_and_the_data_stamp(tmp_path):
    log = tmp_path / "c.log"
    data = (T0 + 7).to_bytes(8, "little").hex().upper()
    log.write_text(f"(1795000000.000250) vcan0 321#{data}\n(1795000000.000300) vcan0 7FF#\n"
                   f"(1795000000.000400) vcan0 322#{data}\n")
    assert stamps.candump_stamps(log, 0x321) == [(T0 + 7, T0 + 250_000)]


def test_latency_summary_counts_loss_duplicates_and_percentiles():
    stamps = [(T0 + i, T0 + i + 1000 * (i + 1)) for i in range(100)] + [(T0, T0 + 5000)]
    r = bench_paths.latency_summary(stamps, sent=102)
    assert (r["received"], r["duplicates"], r["lost"]) == (100, 1, 2)
    assert r["p50_us"] == pytest.approx(50, abs=1.5) and r["max_us"] == 100.0
    assert r["delivered_fps"] > 0 and len(r["cdf_us"]) <= 201


def test_load_rate_reads_both_loads_reports():
    assert stamps.load_rate('{"frames": 9000, "seconds": 1.0000, "enobufs_retries": 0}', 9000) == 9000
    assert stamps.load_rate("144000 frames in 2.000 s (1600 samples)\n", 144000) == 72000
    assert stamps.load_rate("garbage", 10) is None


def test_added_latency_is_over_raw_zenoh_at_the_same_load_and_split_at_the_can_stamp():
    def row(path, rate, p50, system=None, mode="client", **split):
        return {"path": path, "system": system, "mode": mode, "rate": rate, "p50_us": p50, "lost": 0, **split}
    latency = [row("zenoh", 900, 100.0), row("zenoh", 4500, 90.0),
               row("can-to-zenoh", 900, 150.0, "zenoh-node", to_bridge_socket_p50_us=20.0,
                   bridge_socket_to_capture_p50_us=130.0),
               row("can-to-zenoh", 4500, 95.0, "python-ref"),
               row("can-to-zenoh", 4500, 80.0, "zenoh-node", mode="peer"),
               row("zenoh-to-can", 4500, 300.0, "zenoh-node"), row("can-to-zenoh", 8100, 99.0, "zenoh-node")]
    assert bench_paths.added_latency(latency) == [
        {"system": "zenoh-node", "rate": 900, "over_zenoh_us": 50.0, "bus_p50_us": 20.0,
         "from_can_stamp_over_zenoh_us": 30.0},
        {"system": "python-ref", "rate": 4500, "over_zenoh_us": 5.0}]
    md = bench_paths.tables(latency, [])
    assert "zenoh-node at 900 frames/s: +50.0 µs (bus to the bridge's socket 20.0 µs; from the CAN stamp on +30.0 µs)" \
        in md and "python-ref at 4500 frames/s: +5.0 µs\n" in md


def test_can_stamp_split_reads_the_receive_stamp_of_each_frame_from_the_attachment(tmp_path):
    def frame(can_id, sent):
        return can_id.to_bytes(4, "little") + bytes([8, 0, 0, 0]) + sent.to_bytes(8, "little")
    att = bytes([1, 0, 2, 0]) + (7).to_bytes(8, "little") + (T0 + 10_000).to_bytes(8, "little") \
        + (T0 + 30_000).to_bytes(8, "little")
    tsv = tmp_path / "zenoh.tsv"
    tsv.write_text(f"{T0 + 110_000}\tvehicle/can/rx\t{(frame(0x100, T0) + frame(0x200, T0)).hex()}\t{att.hex()}\n"
                   f"{T0 + 200_000}\tvehicle/can/rx\t{frame(0x100, T0).hex()}\t-\n")
    assert stamps.can_stamp_split(tsv, 0x100) == {"to_bridge_socket_p50_us": 10.0,
                                                      "bridge_socket_to_capture_p50_us": 100.0}
    assert stamps.can_stamp_split(tsv, 0x200) == {"to_bridge_socket_p50_us": 30.0,  # its own stamp, the 2nd
                                                      "bridge_socket_to_capture_p50_us": 80.0}
    assert stamps.can_stamp_split(tmp_path / "missing.tsv", 0x100) == {}


def result(system: str, buses: int, lossless: bool, cpu: float, delivered: int | None = None,
           switches: float = 0.0) -> dict:
    offered = 9000 * buses
    return {"system": system, "buses": buses, "instances": 1, "offered": offered * 2, "offered_fps": offered,
            "delivered_fps": delivered if delivered is not None else offered,
            "received": offered * 2 if lossless else offered, "lossless": lossless, "cpu_us_per_frame": cpu,
            "kernel_share": 0.5, "peak_rss_mib": 12.0, "switches_per_frame": switches}


def test_bridge_table_counts_only_sustained_lossless_rates():
    ref, node, batch = "python-ref", "zenoh-node", bench_bridge.SYSTEMS[1]
    results = [result(ref, 1, True, 60), result(ref, 8, False, 30),
               result(node, 1, True, 30), result(node, 8, True, 20, delivered=40000),
               result(batch, 1, True, 6), result(batch, 8, True, 5)]
    table = bench_bridge.table(results)
    best_row = next(line for line in table.splitlines() if line.startswith("| highest lossless"))
    # the immediate mode's 8-bus run arrived whole but was worked off at 40 k/s: it counts at 40 k
    assert best_row.split(" | ")[1:4] == ["40000", "72000", "9000"]
    cpu_row = next(line for line in table.splitlines() if line.startswith("| CPU time per frame"))
    assert cpu_row.split(" | ")[1:4] == ["0.50", "0.10", "1.00"]


def test_bridge_table_reports_each_direction_against_the_reference():
    ref, node = "python-ref", "zenoh-node"
    results = [dict(result(ref, 1, True, 40), direction="zenoh-to-can"),
               dict(result(ref, 2, False, 40), direction="zenoh-to-can"),
               dict(result(node, 1, True, 10), direction="zenoh-to-can"),
               dict(result(node, 2, True, 8), direction="zenoh-to-can"),
               result(node, 1, True, 30), result(ref, 1, True, 60)]
    table = bench_bridge.table(results)
    sections = table.split("\n\n")
    z2c = next(s for s in sections if s.startswith("| zenoh-to-can | zenoh-node | python-ref |"))
    best_row = next(line for line in z2c.splitlines() if line.startswith("| highest lossless"))
    assert best_row.split(" | ")[1:3] == ["18000", "9000"]
    assert "| 2.0x | 1.0x |" in z2c
    assert "| first load with loss | none up to 2 buses | 2 buses | |" in z2c
    cpu_row = next(line for line in z2c.splitlines() if line.startswith("| CPU time per frame"))
    assert cpu_row.split(" | ")[1:3] == ["0.25", "1.00"]  # only the 1-bus load: both lossless there
    c2z = next(s for s in sections if s.startswith("| can-to-zenoh |"))
    assert "| 9000 |" in c2z and "18000" not in c2z


def test_bridge_table_compares_batched_commands_with_the_reference_given_the_same_commands():
    ref, node = "python-ref", "zenoh-node"
    ref_batch, node_batch = f"{ref}{bench_bridge.BATCH}", f"{node}{bench_bridge.BATCH}"
    results = [dict(result(ref, 1, True, 40), direction="zenoh-to-can"),
               dict(result(node, 1, True, 10), direction="zenoh-to-can"),
               dict(result(ref_batch, 1, True, 20), direction="zenoh-to-can"),
               dict(result(node_batch, 1, True, 1), direction="zenoh-to-can"),
               result(ref, 1, True, 60), result(node_batch, 1, True, 3)]
    z2c, c2z = (next(s for s in bench_bridge.table(results).split("\n\n") if s.startswith(f"| {d} |"))
                for d in ("zenoh-to-can", "can-to-zenoh"))
    cpu_row = next(line for line in z2c.splitlines() if line.startswith("| CPU time per frame"))
    # each against its own reference: 10/40 and 1/20, not 1/40
    assert cpu_row.split(" | ")[1:5] == ["0.25", "0.05", "1.00", "1.00"]
    cpu_row = next(line for line in c2z.splitlines() if line.startswith("| CPU time per frame"))
    assert cpu_row.split(" | ")[1:3] == ["0.05", "1.00"]  # CAN -> Zenoh the reference publishes per frame


def switch_run(mode: str, rate: int, switches: float, lossless: bool = True) -> dict:
    return {"direction": "can-to-zenoh", "mode": mode, "rate": rate, "frames": rate * 3,
            "received": rate * 3 if lossless else rate, "lossless": lossless, "ctx_per_frame": switches,
            "ctx_per_frame_by_thread": {"tx-0": switches / 2, "zn-can": switches / 2}, "cpu_us_per_frame": 2.0}


def test_switch_table_judges_batching_against_the_target_and_shows_the_periods_floor():
    rows = bench_bridge.switch_table([switch_run("batching", 900, 0.2), switch_run("batching", 4500, 0.04),
                                      switch_run("batching", 8100, 0.03, lossless=False),
                                      switch_run("immediate", 900, 3.0)]).splitlines()[2:]
    cells = [row.split(" | ") for row in rows]
    assert [c[6] for c in cells] == ["0.111", "0.022", "0.012", "-"]  # 100 periods a second over frames/s
    assert [c[-1] for c in cells] == ["<= 0.05: not met (the floor is above it) |", "<= 0.05: met |",
                                      "<= 0.05: not met |", "for the record |"]


def test_bridge_keys_and_sustained_rate():
    assert bench_bridge.bus_keys("vehicle/can", ["vcan0"], "tx") == ["vehicle/can/tx"]
    assert bench_bridge.bus_keys("vehicle/can", ["vcan0", "vcan1"], "tx") == ["vehicle/can/vcan0/tx",
                                                                               "vehicle/can/vcan1/tx"]
    assert bench_bridge.sustained_fps(9000, T0, T0 + 500_000_000) == 18000
    assert bench_bridge.sustained_fps(0, T0, T0) is None


def test_cpu_of_a_run_falls_back_to_ticks_when_a_thread_ended_in_it():
    """schedstat sums the threads alive when it is read: a thread that ended mid-run takes
    its CPU with it, the process's tick total keeps it."""
    from bench.common import cpu_of_run
    assert cpu_of_run(1.000, 1.01) == (1.000, False)  # the ticks' rounding
    assert cpu_of_run(0.400, 0.390) == (0.400, False)
    assert cpu_of_run(0.400, 0.600) == (0.600, True)
    row = {"direction": "can-to-zenoh", "system": "zenoh-node", "buses": 1, "instances": 1, "offered_fps": 9000,
           "received": 100, "offered": 100, "lossless": True, "delivered_fps": 9000, "cpu_us_per_frame": 6.0,
           "cpu_from_ticks": True, "kernel_share": 0.8, "switches_per_frame": 1.0, "peak_rss_mib": 19.0}
    assert "| 6.0 (ticks) |" in bench_bridge.table([row])


def test_bridge_table_holds_each_system_against_the_floor_too():
    """CAN -> Zenoh the floor (no Zenoh: wake, read, one TCP write per frame) gets a column and a
    row: what the reference and each bridge cost over the least any immediate bridge does."""
    ref, node, floor = "python-ref", "zenoh-node", bench_bridge.FLOOR
    results = [result(ref, 1, True, 40), result(node, 1, True, 20), result(floor, 1, True, 16),
               result(ref, 2, True, 30), result(node, 2, True, 15), result(floor, 2, False, 10)]
    table = bench_bridge.table(results)
    header = next(line for line in table.splitlines() if line.startswith("| can-to-zenoh |") and "target" in line)
    assert header == "| can-to-zenoh | zenoh-node | python-ref | floor | target |"
    cpu_row = next(line for line in table.splitlines() if line.startswith("| CPU time per frame"))
    assert cpu_row.split(" | ")[1] == "0.50" and cpu_row.split(" | ")[-2] == "0.40"
    floor_row = next(line for line in table.splitlines() if line.startswith("| ... relative to the floor"))
    assert floor_row.split(" | ")[1:4] == ["1.25", "2.50", "1.00"]  # only the 1-bus load: the floor lost at 2


def test_bridge_table_holds_each_system_against_the_floor_of_its_structure_too():
    """The floor with a thread per bus (zenoh-node's structure) gets its own column and row, apart
    from the one-thread floor's: what a bridge costs over the least a bridge reading as it does costs."""
    ref, node, floor, per_bus = "python-ref", "zenoh-node", bench_bridge.FLOOR, bench_bridge.FLOOR_PER_BUS
    results = [result(ref, 1, True, 40), result(node, 1, True, 18), result(floor, 1, True, 18),
               result(per_bus, 1, True, 18), result(ref, 2, True, 30), result(node, 2, True, 17),
               result(floor, 2, True, 8.5), result(per_bus, 2, True, 17)]
    table = bench_bridge.table(results)
    header = next(line for line in table.splitlines() if line.startswith("| can-to-zenoh |") and "target" in line)
    assert header == "| can-to-zenoh | zenoh-node | python-ref | floor | floor-per-bus | target |"
    floor_row = next(line for line in table.splitlines() if line.startswith("| ... relative to the floor (wake"))
    assert floor_row.split(" | ")[1] == "1.50"  # median of 18 / 18 and 17 / 8.5
    per_bus_row = next(line for line in table.splitlines() if line.startswith("| ... relative to the floor-per-bus"))
    assert per_bus_row.split(" | ")[1:5] == ["1.00", "1.99", "0.75", "1.00"]
    assert "floor-per-bus" not in bench_bridge.DIRECTION_SYSTEMS["zenoh-to-can"]


def test_bridge_table_judges_switches_at_the_loads_both_forward_losslessly():
    ref, batch = "python-ref", bench_bridge.SYSTEMS[1]
    results = [result(ref, 1, True, 40), result(batch, 1, True, 3, switches=0.04),
               result(ref, 2, True, 40), result(batch, 2, True, 3, switches=0.03),
               result(ref, 4, False, 40), result(batch, 4, True, 3, switches=0.09)]
    table = bench_bridge.table(results)
    row = next(line for line in table.splitlines() if line.startswith("| context switches per frame"))
    assert row.split(" | ")[1:3] == ["0.040", "0.000"]  # not the 4-bus load: the reference lost frames there


def test_bridge_ratios_are_judged_on_the_median_of_repeated_runs(monkeypatch):
    """After the sweep every system runs again at the loads where one of its ratios is judged (and
    only there), and the ratio takes each load's median: one slow first run does not decide it, a
    repeat that lost frames is counted and left out."""
    ref, node, floor = "python-ref", "zenoh-node", bench_bridge.FLOOR
    results = [dict(r, direction="can-to-zenoh") for r in (
        result(ref, 1, True, 40), result(node, 1, True, 16), result(floor, 1, True, 10),
        result(ref, 2, True, 30), result(node, 2, False, 15), result(floor, 2, True, 9),
        result(ref, 4, False, 20), result(floor, 4, True, 8))]
    again = {(node, 1): [10, 10], (ref, 1): [40, 44], (floor, 1): [8, 12], (ref, 2): [30, 31], (floor, 2): [9, 9]}
    calls = []

    def run_once(args, system, buses, direction):
        calls.append((system, buses))
        cpu = again[(system, buses)].pop(0)
        return dict(result(system, buses, not (system == floor and cpu == 12), cpu), direction=direction)

    monkeypatch.setattr(bench_bridge, "run_once", run_once)
    bench_bridge.judged_runs(None, results, "can-to-zenoh", 3)
    # node lost at 2 buses and the reference at 4: the floor's 4-bus load judges nothing
    assert sorted(set(calls)) == sorted(again) and len(calls) == 10
    by = {(r["system"], r["buses"]): r for r in results}
    assert by[(node, 1)]["cpu_us_per_frame_runs"] == [16, 10, 10]
    assert by[(floor, 1)]["cpu_us_per_frame_runs"] == [10, 8] and by[(floor, 1)]["extra_runs_lossy"] == 1
    assert "cpu_us_per_frame_runs" not in by[(floor, 4)]
    table = bench_bridge.table(results)
    cpu_row = next(line for line in table.splitlines() if line.startswith("| CPU time per frame"))
    assert cpu_row.split(" | ")[1] == "0.25"  # 10 / 40; the first runs alone said 0.40
    floor_row = next(line for line in table.splitlines() if line.startswith("| ... relative to the floor"))
    assert floor_row.split(" | ")[1] == "1.11"  # 10 / median(10, 8) = 9


def test_paired_added_latency_is_judged_on_the_median_of_the_pairs():
    """One slow pair does not fail a cell; a cell whose median is over the target fails the row."""
    def cell(path, system, rate, added):
        return {"path": path, "system": system, "rate": rate, "added_us": added,
                "median_added_us": statistics.median(added)}
    cells = [cell("can-to-zenoh", "zenoh-node", 900, [10.0, 200.0, 20.0]),
             cell("can-to-zenoh", "zenoh-node", 8100, [40.0, 45.0, 90.0]),
             cell("zenoh-to-can", "zenoh-node", 900, [10.0, 60.0, 70.0]),
             cell("zenoh-to-can", "zenoh-node", 8100, [-5.0, 0.0, 5.0])]
    table = bench_paths.paired_table(cells)
    rows = {tuple(line.split(" | ")[:2]): line for line in table.splitlines() if line.startswith("| ")}
    c2z = rows[("| can-to-zenoh", "zenoh-node")]
    assert "+20.0 (+10.0, +200.0, +20.0)" in c2z and "+45.0" in c2z and c2z.endswith("| met |")
    assert rows[("| zenoh-to-can", "zenoh-node")].endswith("| not met |")  # 60 at 10 %


def test_paired_can_to_zenoh_cell_splits_at_the_can_stamp(monkeypatch):
    """A CAN -> Zenoh cell gives the bus's hop and the share from the bridge's CAN stamp on, as
    medians over the pairs; a Zenoh -> CAN cell (no stamp) gives neither."""
    raws = iter([100.0, 120.0, 110.0] * 2)
    hops = iter([10.0, 30.0, 20.0])

    def fake_measure(args, path, system, mode, rate, seconds):
        if path == "zenoh":
            return {"p50_us": next(raws)}
        if path == "can-to-zenoh":
            hop = next(hops)
            return {"p50_us": 200.0, "to_bridge_socket_p50_us": hop, "bridge_socket_to_capture_p50_us": 200.0 - hop}
        return {"p50_us": 150.0}
    monkeypatch.setattr(bench_paths, "measure", fake_measure)
    monkeypatch.setattr(bench_paths, "PAIRED_PATHS", ("can-to-zenoh", "zenoh-to-can"))
    monkeypatch.setattr(bench_paths, "PAIRED_SYSTEMS", ("zenoh-node",))
    c2z, z2c = bench_paths.paired_added(None, {"90%": 8100}, 3)
    assert c2z["added_us"] == [100.0, 80.0, 90.0] and c2z["median_added_us"] == 90.0
    assert c2z["median_bus_us"] == 20.0
    assert c2z["median_from_can_stamp_us"] == 70.0  # 90, 50, 70: (200 - hop) - raw per pair
    assert "median_bus_us" not in z2c
    table = bench_paths.paired_table([c2z, z2c])
    assert "+90.0 (+100.0, +80.0, +90.0; bus 20.0, from the stamp +70.0)" in table
    assert "| zenoh-to-can | zenoh-node | +40.0 (+50.0, +30.0, +40.0) |" in table


def test_bunched_share_tells_a_load_sent_in_pairs_from_one_paced_frame_by_frame():
    gap = 1e9 / 8100
    even = [T0 + round(i * gap) + (i % 7) * 1000 for i in range(1000)]  # late by up to 6 µs of 123
    pairs = [T0 + round((i // 2) * 2 * gap) + (i % 2) * 8000 for i in range(1000)]  # every other one 8 µs after
    assert stamps.bunched_share(even, 8100) == 0.0
    assert stamps.bunched_share(pairs, 8100) == pytest.approx(0.5, abs=0.002)
    # a frame captured twice is one send
    assert stamps.bunched_share(pairs + pairs, 8100) == pytest.approx(0.5, abs=0.002)
    assert stamps.bunched_share([T0], 8100) is None and stamps.bunched_share(even, 0) is None


def test_paired_cells_are_not_judged_where_the_loads_differ_in_shape(monkeypatch):
    """Raw Zenoh's load sent in pairs where the bridge's did not: the cell shows both shares and the
    row has no verdict, met or not; loads of one shape are judged as before."""
    def fake_measure(args, path, system, mode, rate, seconds):
        if path == "zenoh":
            return {"p50_us": 100.0, "bunched": 0.44 if rate == 8100 else 0.02}
        return {"p50_us": 130.0, "bunched": 0.01}
    monkeypatch.setattr(bench_paths, "measure", fake_measure)
    monkeypatch.setattr(bench_paths, "PAIRED_PATHS", ("can-to-zenoh",))
    monkeypatch.setattr(bench_paths, "PAIRED_SYSTEMS", ("zenoh-node",))
    cells = bench_paths.paired_added(None, {"10%": 900, "90%": 8100}, 3)
    assert [c["median_bunched"] for c in cells] == [[0.02, 0.01], [0.44, 0.01]]
    row = next(line for line in bench_paths.paired_table(cells).splitlines() if line.startswith("| can-to-zenoh"))
    assert "sent bunched: raw 0.44, the bridge's load 0.01" in row
    assert row.endswith("| not judged: the loads differ in shape |")
    row = next(line for line in bench_paths.paired_table(cells[:1]).splitlines() if line.startswith("| can-to-zenoh"))
    assert row.endswith("| met |") and "bunched" not in row


def test_bridge_table_says_where_a_lossy_run_lost_its_frames():
    node = "zenoh-node"
    lossy = dict(result(node, 8, False, 4), direction="zenoh-to-can",
                 accounts={"hub_rx_drops": 1651, "tx_samples": 144000, "tx_frames": 144000, "tx_queue_full": 0})
    row = next(line for line in bench_bridge.table([lossy]).splitlines() if line.startswith("| zenoh-to-can | zenoh"))
    assert "| no (hub_rx_drops 1651, tx_samples 144000, tx_frames 144000) |" in row
    assert bench_bridge.lossless_cell(dict(lossy, lossless=True)) == "yes"
    assert bench_bridge.lossless_cell(dict(lossy, accounts={})) == "no"


def test_callgrind_stages_count_with_the_median_of_the_runs_and_show_their_range(monkeypatch):
    """One run of the same build can be a few per cent off (the transmit task's wakeups): a
    stage's count is the median over the runs, its range is said beside it."""
    from bench import callgrind
    process = iter([12_150, 11_848, 12_171])
    monkeypatch.setattr(callgrind, "measure", lambda args, low_latency: {"put": 3631, "process_rx": next(process)})
    measured = callgrind.measure_runs(None, False, 3)
    assert measured[0] == {"put": 3631, "process_rx": 12_150}
    assert callgrind.spread(measured, "process_rx") == "12150 [11848-12171]"
    assert callgrind.spread(measured, "put") == "3631"  # the same in every run: no range
