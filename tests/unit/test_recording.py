"""recording.mcap in ROS 2's encoding, on a synthetic run (the powertrain trace on
the bus, a Zenoh capture that lost one frame, the smoke scenario's DBC): decoded
by the MCAP ROS 2 decoder (mcap-ros2-support) and by Rerun's own MCAP import
(`rerun mcap convert`), every CAN frame of can.log is there, in order, and the
signals are plottable Float64 series; `canbench view recording.mcap` shows the
same frames through the live viewer's loggers."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from canbench import analysis, dbc, oracle, recording, scenario, wire

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
mcap_ros2 = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (pip install -e '.[viewer]')")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("run")
    sc = scenario.load(REPO / "scenarios" / "smoke.yaml")
    (tmp / "can.log").write_text((REPO / "scenarios" / "traces" / "powertrain-2s.log").read_text())
    frames = oracle.read_candump(tmp / "can.log", "vcan0")
    with open(tmp / "zenoh.tsv", "w") as f:  # zn-capture's format
        for i, o in enumerate(frames):
            if i != 50:
                f.write(f"{o.t_ns + 400_000}\tvehicle/can/rx\t{wire.encode(o.frame).hex()}\t"
                        f"{wire.encode_attachment(i, [o.t_ns]).hex()}\n")
    result = analysis.analyse(sc, "synthetic", tmp, "vehicle/can", {}, None, 2.0)
    result.metrics["passed"] = False
    t0 = result.buses[0].bus_frames[0].t_ns
    result.buses[0].commands = [oracle.Observed(wire.Frame(0x7A0, 2, b"\x01\x02"), t0 + 1000, 0, origin="commands.tsv")]
    recording.write_mcap(result, tmp / "recording.mcap", dbc.load_dbc(sc.dbc))
    return tmp


def bus_frames(run_dir: Path) -> list[tuple[int, int, bool, int, str]]:
    return [(o.t_ns, o.frame.can_id, o.frame.remote, o.frame.dlc, o.frame.data.hex())
            for o in oracle.read_candump(run_dir / "can.log", "vcan0")]


def frame_tuple(stamp: int, m) -> tuple[int, int, bool, int, str]:
    get = m.get if isinstance(m, dict) else lambda k: getattr(m, k)
    return stamp, get("id"), get("is_rtr"), get("dlc"), "" if get("is_rtr") else bytes(get("data"))[:get("dlc")].hex()


def test_ros2_decoder_finds_every_frame_of_can_log(run_dir):
    frames, zenoh, speeds, latencies, commands = [], 0, [], [], []
    with open(run_dir / "recording.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[mcap_ros2.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
            if channel.topic == "/can/vcan0":
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                assert stamp == message.log_time and msg.header.frame_id == "vcan0"
                frames.append(frame_tuple(stamp, msg))
            elif channel.topic == "/zenoh/vcan0":
                zenoh += 1
            elif channel.topic == "/signals/vcan0/EngineData/EngineSpeed":
                speeds.append(msg.data)
            elif channel.topic == "/latency/vcan0":
                latencies.append(msg.data)
            elif channel.topic == "/commands/vcan0":
                commands.append(frame_tuple(message.log_time, msg))
    assert frames == bus_frames(run_dir)  # all 388, in order, ids and data
    assert zenoh == 387 and len(latencies) == 387 and all(abs(v - 0.4) < 1e-9 for v in latencies)
    assert len(speeds) == 200 and len(set(speeds)) > 10
    assert commands == [(1700000000005774000, 0x7A0, False, 2, "0102")]


def test_rerun_imports_the_recording(run_dir):
    rerun = shutil.which("rerun")
    if not rerun:
        pytest.skip("the rerun CLI (rerun-sdk) is not installed")
    rrd = run_dir / "imported.rrd"
    subprocess.run([rerun, "mcap", "convert", str(run_dir / "recording.mcap"), "-o", str(rrd)], check=True,
                   capture_output=True, timeout=60)
    from canbench.viewer import read_rrd_columns
    columns = read_rrd_columns(rrd)
    messages = columns["/can/vcan0"]["can_msgs.msg.Frame:message"]  # Rerun's ROS 2 reflection decoder
    frames = [frame_tuple(m[0]["header"]["stamp"]["sec"] * 1_000_000_000 + m[0]["header"]["stamp"]["nanosec"], m[0])
              for m in messages]
    assert frames == bus_frames(run_dir)
    assert len(columns["/signals/vcan0/EngineData/EngineSpeed"]["std_msgs.msg.Float64:message"]) == 200


def test_canbench_view_shows_the_recording(run_dir):
    pytest.importorskip("rerun", reason="the viewer needs rerun-sdk")
    rrd = run_dir / "viewed.rrd"
    subprocess.run([sys.executable, "-m", "canbench.cli", "view", str(run_dir / "recording.mcap"), "--dbc",
                    str(REPO / "scenarios" / "dbc" / "powertrain.dbc"), "--save", str(rrd)], check=True,
                   capture_output=True, timeout=120)
    from canbench.viewer import read_rrd
    logged = read_rrd(rrd)
    shown = sum(len(v) for k, v in logged.items() if k.startswith("/can/vcan0/") and k.endswith("/raw"))
    assert shown == len(bus_frames(run_dir))
    assert logged["/can/vcan0/0C0/EngineSpeed"] == logged["/signals/vcan0/EngineData/EngineSpeed"]  # both decodings
    assert len(logged["/signals/vcan0/EngineData/EngineSpeed"]) == 200  # the recording's signals
    assert logged["/commands/vcan0/7A0/raw"] == ["7A0#0102"]


def test_signal_topics_are_ros2_names_whatever_the_database_calls_them():
    # a KCD may name a message 'Engine Data' and a signal '2nd.Gear': no ROS 2 topic (ros2 bag play
    # cannot publish on one); two names that would be one topic stay apart
    names = recording.TopicNames()
    assert names.topic("/signals/vcan0", "Engine Data", "2nd.Gear") == "/signals/vcan0/Engine_Data/_2nd_Gear"
    assert names.topic("/signals/vcan0", "Engine Data", "Engine-Speed") == "/signals/vcan0/Engine_Data/Engine_Speed"
    assert names.topic("/signals/vcan0", "Engine_Data", "Engine_Speed") == "/signals/vcan0/Engine_Data/Engine_Speed_2"
    assert names.topic("/signals/vcan0", "Engine Data", "Engine-Speed") == "/signals/vcan0/Engine_Data/Engine_Speed"
    assert names.topic("/signals/vcan0", "EngineData", "Speed") == "/signals/vcan0/EngineData/Speed"  # a DBC's, as is
