"""What summarise and scaffold infer from recordings like real cars' (a 350Z, a Genesis, a GT86
through candump and PCAN loggers): each interface's load over its own span, a periodic id with a
USB logger's jitter, an event-periodic message with a frame the logger missed."""
from __future__ import annotations

import random

import pytest

from canbench import authoring, cli, scenario

pytestmark = pytest.mark.unit


def write(path, frames):
    path.write_text("".join(f"({t:.6f}) {iface} {x}\n" for t, iface, x in sorted(frames)))
    return path


def test_each_interfaces_load_is_over_its_own_span(tmp_path):
    # can0 recorded 10 s at 1 frame/ms; can1 joined 10 s later: merged span 20 s
    frames = [(1000 + i / 1000, "can0", "100#0011223344556677") for i in range(10_000)]
    frames += [(1010 + i / 100, "can1", "200#00") for i in range(1000)]
    alone = authoring.summarise(write(tmp_path / "a.log", frames[:10_000]))
    both = authoring.summarise(write(tmp_path / "b.log", frames))
    assert both.loads["can0"] == pytest.approx(alone.load_pct, rel=0.01)  # was half of it


def test_a_10_ms_id_with_a_usb_loggers_jitter_is_gated(tmp_path):
    # as a Genesis sedan's 0x280/0x316 recorded through candump: every gap 7.6..12.4 ms, the
    # frames' count that of 10 ms, but a fifth to a third of the gaps beyond +-10 % (not gated)
    rng = random.Random(1)
    t, frames = 1000.0, []
    for _ in range(1500):
        frames.append((t, "can0", "280#00"))
        t += rng.choice((0.0084, 0.0088, 0.0100, 0.0112, 0.0116)) if rng.random() < 0.5 else 0.0100
    write(tmp_path / "g.log", frames)
    assert cli.main(["scaffold", str(tmp_path / "g.log"), "--name", "g", "--out", str(tmp_path / "g.yaml")]) == 0
    assert scenario.load(tmp_path / "g.yaml").expect["cycle_time"].get("ids", {}) == {"280": 10.0}


DBC = """VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\nBO_ 256 Status: 8 ECU
 SG_ Value : 0|8@1+ (1,0) [0|255] "" Vector__XXX\n
BA_DEF_ BO_  "GenMsgCycleTime" INT 0 65535;
BA_DEF_ BO_  "GenMsgSendType" ENUM  "Cyclic","Event","EventPeriodic";
BA_DEF_DEF_  "GenMsgCycleTime" 0;\nBA_DEF_DEF_  "GenMsgSendType" "Cyclic";
BA_ "GenMsgCycleTime" BO_ 256 10;\nBA_ "GenMsgSendType" BO_ 256 2;\n"""


def test_an_event_periodic_message_with_one_frame_the_logger_missed_passes_its_own_gate(tmp_path):
    from types import SimpleNamespace
    (tmp_path / "s.dbc").write_text(DBC)
    frames = [(1000 + i / 100, "can0", f"100#{i % 256:02X}00000000000000") for i in range(300) if i != 150]
    write(tmp_path / "ep.log", frames)
    assert cli.main(["scaffold", str(tmp_path / "ep.log"), "--name", "ep", "--dbc", str(tmp_path / "s.dbc"),
                     "--out", str(tmp_path / "ep.yaml")]) == 0
    sc = scenario.load(tmp_path / "ep.yaml")
    # the faithful replay's bus and Zenoh: the recording's gaps (median 10 ms, longest 20 ms)
    side = {"count": 299, "cycle_p50_ms": 10.0, "cycle_min_ms": 10.0, "cycle_max_ms": 20.0}
    from canbench import checks
    run = SimpleNamespace(scenario=sc, buses=[SimpleNamespace(bus="vcan0", cycle_times={
        "100": {"can": side, "zenoh": dict(side)}})])
    assert checks.cycle_time(run) == []


def test_an_interface_with_a_short_burst_is_not_loaded_beyond_100_pct(tmp_path):
    # can1: three 8-byte frames back to back at 500 kbit/s (0.27 ms each, the worst-case stuffing
    # the load is counted with) and nothing else; first to last stamp left out a frame's time: 150 %
    frames = [(1700000000 + i * 0.01, "can0", "100#0011223344556677") for i in range(1000)]
    frames += [(1700000005 + k * 0.00027, "can1", "200#0011223344556677") for k in range(3)]
    s = authoring.summarise(write(tmp_path / "rec.log", frames))
    assert round(s.loads["can1"], 6) <= 100.0 and round(s.load_pct, 6) <= 100.0, s.loads
