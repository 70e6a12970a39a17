"""The reference bridge for benchmarks: what a user writes first — python-can
`socketcan` + eclipse-zenoh, one thread per bus, the same 16-byte wire format
and keys as zenoh-node (CAN -> Zenoh one sample per frame; Zenoh -> CAN on
the tx key). Declares a liveliness token like the bridge, so the same
readiness wait applies (`--no-token`: none, as a user's bridge that announces
nothing: tests/compose/test_device.py runs it as DEVICE_ANNOUNCES=0's device).
Its Zenoh settings are $ZENOH_CONFIG's when set (a device's identity), then
--router as the one endpoint, client mode, no scouting. Not a product: the
baseline `make bench` measures zenoh-node against, in the same run.

  python -m bench.refbridge --router tcp/127.0.0.1:7447 --can vcan0,vcan1"""
from __future__ import annotations

import argparse
import signal
import threading

import can
import zenoh

from canbench import wire
from canbench.runkeys import open_session


def frame_of(msg: can.Message) -> wire.Frame:
    return wire.Frame(msg.arbitration_id, msg.dlc, b"" if msg.is_remote_frame else bytes(msg.data),
                      msg.is_extended_id, msg.is_remote_frame)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--router", default="tcp/127.0.0.1:7447")
    ap.add_argument("--can", default="vcan0")
    ap.add_argument("--prefix", default="vehicle/can")
    ap.add_argument("--no-token", action="store_true", help="declare no liveliness token")
    args = ap.parse_args()
    buses = args.can.split(",")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = open_session(args.router)
    threads: list[threading.Thread] = []
    keep: list[object] = []  # subscribers and tokens live as long as the bridge
    for name in buses:
        key = f"{args.prefix}/rx" if len(buses) == 1 else f"{args.prefix}/{name}/rx"
        tx_key = key[:-2] + "tx"
        bus = can.Bus(interface="socketcan", channel=name)
        pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)

        def on_command(sample: zenoh.Sample, bus: can.BusABC = bus) -> None:
            try:
                for f in wire.decode_batch(sample.payload.to_bytes()):
                    bus.send(can.Message(arbitration_id=f.can_id, is_extended_id=f.extended,
                                         is_remote_frame=f.remote, dlc=f.dlc, data=f.data), timeout=1)
            except (wire.WireError, can.CanError):
                pass  # the reference counts nothing: it is the naive baseline

        keep.append(session.declare_subscriber(tx_key, on_command))

        def forward(bus: can.BusABC = bus, pub: zenoh.Publisher = pub) -> None:
            while not stop.is_set():
                msg = bus.recv(timeout=0.2)
                if msg is not None and not msg.is_error_frame:
                    pub.put(wire.encode(frame_of(msg)))
        threads.append(threading.Thread(target=forward, daemon=True))
        if not args.no_token:
            keep.append(session.liveliness().declare_token(f"{args.prefix}/bridges/python-ref/{name}/client"))
    for t in threads:
        t.start()
    stop.wait()
    session.close()


if __name__ == "__main__":
    main()
