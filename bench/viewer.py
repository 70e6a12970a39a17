"""Viewer throughput: `canbench view --save` under CAN frames at --rate frames/s (the
bridge's 16-byte format, --batch frames per sample as its batching mode sends them)
plus a 640x480 rgb8 sensor_msgs/Image at 10 Hz and a robot's /joint_states (30 joints,
position, velocity and effort: 90 scalars a message) at --joints-hz from an
rmw_zenoh-style node, for --seconds. Reports the rate the viewer logged at (frames published / time until it
had logged them all), samples dropped (its queue is bounded: QUEUE_SAMPLES), its
peak and final RSS, CPU, and the frames and images read back from the .rrd.

  python3 -m bench.viewer [--rate 50000] [--seconds 10] [--dbc scenarios/dbc/powertrain.dbc]

With --dbc the frames are the DBC's own messages (its ids, lengths, extended flags), so
every frame is decoded into signals, and the signals in the .rrd are counted too.

Zenoh: this script listens as a peer on a loopback port and the viewer connects to it
(or both to --router ENDPOINT); multicast scouting off; the load stops by itself."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zenoh

from canbench import ros2, ros2_msgs, wire
from canbench.dbc import decode_signals, load_dbc
from canbench.rig import free_port

from .common import cpu_s, machine_line, rss_mib, run_id_and_output

DRAIN_TIMEOUT_S = 60.0


def stats(session) -> dict | None:
    replies = [r for r in session.get("canbench/viewers/*/stats") if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


def wait(condition, what: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise SystemExit(f"bench.viewer: timed out waiting for {what}")
        time.sleep(0.05)


def image_msg() -> ros2_msgs.Image:
    pixels = np.random.default_rng(1).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    return ros2_msgs.Image(header=ros2_msgs.Header(frame_id="camera"), height=480, width=640, encoding="rgb8",
                           step=640 * 3, data=pixels.tobytes())


JOINTS = [f"joint_{i}" for i in range(30)]


def joint_state_msg(k: int) -> ros2_msgs.JointState:
    """A 30-joint robot's /joint_states as ros2_control's joint_state_broadcaster publishes it."""
    return ros2_msgs.JointState(header=ros2_msgs.Header(stamp=ros2_msgs.Time(1_700_000_000, k)), name=JOINTS,
                                position=[k / 1000 + i for i in range(30)], velocity=[0.5] * 30, effort=[1.5] * 30)


def batches(count: int, batch: int, db=None) -> list[bytes]:
    """Distinct ids (0x100 + i % 64) and data, as a busy bus would carry them; with a DBC
    (cantools database) its messages in turn, each with its length, so every frame decodes."""
    messages = db.messages if db is not None else []
    frames = []
    for i in range(batch * 64):
        data = (i * 2654435761 % 2**64).to_bytes(8, "little")
        if messages:
            m = messages[i % len(messages)]
            frames.append(wire.Frame(m.frame_id, m.length, data[:m.length], m.is_extended_frame))
        else:
            frames.append(wire.Frame(0x100 + i % 64, 8, data))
    encoded = [wire.encode(f) for f in frames]
    return [b"".join(encoded[(k * batch) % len(frames):(k * batch) % len(frames) + batch]) for k in range(count)]


def signals_in(payload: bytes, db) -> int:
    """How many signal values the viewer logs for one sample's frames."""
    return sum(len(d[1]) for f in wire.decode_batch(payload) if (d := decode_signals(db, f))) if db else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate", type=int, default=50_000, help="CAN frames/s")
    ap.add_argument("--batch", type=int, default=50, help="frames per Zenoh sample")
    ap.add_argument("--image-hz", type=float, default=10.0)
    ap.add_argument("--joints-hz", type=float, default=200.0, help="/joint_states messages a second")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--dbc", help="let the viewer decode signals too")
    ap.add_argument("--router", help="a zenohd endpoint for both sides instead of peer to peer")
    ap.add_argument("--out", help="output directory (default reports/bench/<run-id>)")
    args = ap.parse_args()
    run_id, out = run_id_and_output(args)

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    if args.router:
        endpoint = args.router
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    else:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    session = zenoh.open(conf)
    node = ros2.Node(session, "camera_node")
    can_pub = session.declare_publisher("vehicle/can/rx", congestion_control=zenoh.CongestionControl.BLOCK)
    bridge_token = session.liveliness().declare_token("vehicle/can/bridges/bench/vcan0/client")

    tmp = Path(tempfile.mkdtemp(prefix="bench-viewer-"))
    rrd = tmp / "viewer.rrd"
    cmd = [sys.executable, "-m", "canbench.cli", "view", "--zenoh-connect", endpoint, "--auto-subscribe",
           "--save", str(rrd), *(["--dbc", args.dbc] if args.dbc else [])]
    viewer = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rss: list[float] = []
    try:
        wait(lambda: viewer.poll() is not None or stats(session), "the viewer's stats", 30)
        image_pub = node.publisher("/camera/image", "sensor_msgs/msg/Image")
        wait(lambda: image_pub.key in (stats(session) or {}).get("subscriptions", []), "the image subscription", 30)
        image = image_msg().serialize()
        joints_pub = node.publisher("/joint_states", "sensor_msgs/msg/JointState")
        wait(lambda: joints_pub.key in (stats(session) or {}).get("subscriptions", []), "the joints subscription", 30)
        samples_per_s = args.rate / args.batch
        db = load_dbc(Path(args.dbc)) if args.dbc else None
        payloads = batches(1000, args.batch, db)
        signals_per_payload = [signals_in(p, db) for p in payloads]
        sent_samples = sent_frames = sent_signals = images = joint_states = 0
        start = time.monotonic()
        next_image = next_rss = next_joints = start
        while (now := time.monotonic()) - start < args.seconds:
            due = int((now - start) * samples_per_s)
            while sent_samples < due:  # paced by the clock: a late loop catches up, never runs ahead
                can_pub.put(payloads[sent_samples % len(payloads)])
                sent_signals += signals_per_payload[sent_samples % len(payloads)]
                sent_samples += 1
                sent_frames += args.batch
            if now >= next_image:
                image_pub.put(image)
                images += 1
                next_image += 1 / args.image_hz
            if now >= next_joints:
                joints_pub.put(joint_state_msg(joint_states))
                joint_states += 1
                next_joints += 1 / args.joints_hz
            if now >= next_rss:
                rss.append(rss_mib(viewer.pid))
                next_rss += 0.5
            time.sleep(0.0005)
        published_s = time.monotonic() - start
        total = sent_samples + images + joint_states

        def drained() -> bool:
            rss.append(rss_mib(viewer.pid))
            s = stats(session)
            return bool(s) and s["logged"] + s["dropped"] >= total

        wait(drained, "the viewer to log what was sent", DRAIN_TIMEOUT_S)
        logged_s = time.monotonic() - start
        final = stats(session) or {}
        cpu = cpu_s(viewer.pid)
    finally:
        viewer.send_signal(subprocess.signal.SIGINT)
        viewer.communicate(timeout=120)
        node.close()
        bridge_token.undeclare()
        session.close()

    from canbench.viewer import read_rrd_columns
    columns = read_rrd_columns(rrd)
    frames_in_rrd = sum(len(c.get("TextLog:text", [])) for e, c in columns.items() if e.startswith("/can/rx/"))
    signals_in_rrd = sum(len(c.get("Scalars:scalars", [])) for e, c in columns.items() if e.startswith("/can/rx/"))
    images_in_rrd = len(columns.get("/ros2/camera/image", {}).get("Image:buffer", []))
    joint_values_in_rrd = sum(len(c.get("Scalars:scalars", [])) for e, c in columns.items()
                              if e.startswith("/ros2/joint_states/"))
    result = {
        "run_id": run_id, "machine": machine_line(), "rate_target": args.rate, "batch": args.batch,
        "image_hz": args.image_hz, "joints_hz": args.joints_hz, "seconds": args.seconds, "dbc": bool(args.dbc),
        "joint_states_sent": joint_states, "joint_values_in_rrd": joint_values_in_rrd,
        "frames_sent": sent_frames, "images_sent": images, "published_s": round(published_s, 2),
        "logged_s": round(logged_s, 2), "frames_per_s_logged": round(sent_frames / logged_s),
        "dropped_samples": final.get("dropped"), "malformed": final.get("malformed"),
        "rss_peak_mib": round(max(rss), 1), "rss_first_mib": round(rss[0], 1), "cpu_s": round(cpu, 1),
        "rss_mib_each_second": [round(v) for v in rss[::2]],
        "frames_in_rrd": frames_in_rrd, "images_in_rrd": images_in_rrd,
        "signals_sent": sent_signals, "signals_in_rrd": signals_in_rrd,
        "rrd_mib": round(rrd.stat().st_size / 2**20, 1),
    }
    (out / "viewer.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    rrd.unlink()
    ok = (result["dropped_samples"] == 0 and frames_in_rrd == sent_frames and images_in_rrd == images
          and signals_in_rrd == sent_signals and joint_values_in_rrd == joint_states * 3 * len(JOINTS)
          and result["frames_per_s_logged"] >= args.rate * 0.95)
    print(f"bench.viewer: {'PASS' if ok else 'FAIL'}: {result['frames_per_s_logged']} frames/s logged "
          f"(target {args.rate}), {images_in_rrd}/{images} images, {signals_in_rrd}/{sent_signals} signal values, "
          f"{joint_values_in_rrd}/{joint_states * 3 * len(JOINTS)} joint values, "
          f"{result['dropped_samples']} samples dropped, "
          f"RSS peak {result['rss_peak_mib']} MiB; {out / 'viewer.json'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
