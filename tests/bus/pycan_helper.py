"""python-can driver for the conformance suite, run as a subprocess under the
bus's environment (LD_PRELOAD for the userspace hub).

  recv  --channel vcan0 --count N [--filters JSON] [--own] [--fd] [--errors] [--join]
        prints "ready" once bound, then one JSON object per received message
  send  --channel vcan0 --frames JSON [--fd] [--own]
        sends the frames; with --own also reads them back and prints them
  readers --specs JSON
        several recv readers in one process (a list of {channel, count, filters, own, fd,
        errors, join}), each its own can.Bus: prints "ready" once all are bound, then each
        reader's messages with "reader": <index>. Under the real-kernel lane's emulation a
        Python start costs seconds; this is the same python-can code, started once.
"""
from __future__ import annotations

import argparse
import json
import socket
import sys
import threading

import can

CAN_RAW_ERR_FILTER = 2  # linux/can/raw.h; not exported by Python's socket module
CAN_RAW_JOIN_FILTERS = 6


def message_json(msg: can.Message, **extra) -> str:
    return json.dumps({**extra,
        "id": msg.arbitration_id, "ext": msg.is_extended_id, "rtr": msg.is_remote_frame,
        "err": msg.is_error_frame, "fd": msg.is_fd, "dlc": msg.dlc, "data": msg.data.hex(),
        "channel": msg.channel, "is_rx": msg.is_rx, "ts": msg.timestamp,
    })


def to_message(frame: dict) -> can.Message:
    return can.Message(
        arbitration_id=frame["id"], is_extended_id=frame.get("ext", False),
        is_remote_frame=frame.get("rtr", False), is_error_frame=frame.get("err", False),
        is_fd=frame.get("fd", False), dlc=frame.get("dlc"),
        data=bytes.fromhex(frame.get("data", "")), channel=frame.get("channel"),
    )


def open_bus(spec: dict) -> can.BusABC:
    kwargs: dict = {"interface": "socketcan", "channel": spec.get("channel", "vcan0"), "fd": spec.get("fd", False),
                    "receive_own_messages": spec.get("own", False)}
    if spec.get("filters"):
        filters = spec["filters"]
        kwargs["can_filters"] = json.loads(filters) if isinstance(filters, str) else filters
    bus = can.Bus(**kwargs)
    if not spec.get("errors"):
        # python-can subscribes to all error classes; a plain reader does not
        bus.socket.setsockopt(socket.SOL_CAN_RAW, CAN_RAW_ERR_FILTER, 0)
    if spec.get("join"):
        bus.socket.setsockopt(socket.SOL_CAN_RAW, CAN_RAW_JOIN_FILTERS, 1)
    return bus


def readers(specs: list[dict], timeout: float) -> int:
    buses = [open_bus(spec) for spec in specs]
    got: list[list[str]] = [[] for _ in specs]

    def read(i: int) -> None:
        for _ in range(specs[i].get("count", 1)):
            msg = buses[i].recv(timeout)
            if msg is None:
                return
            got[i].append(message_json(msg, reader=i))

    threads = [threading.Thread(target=read, args=(i,)) for i in range(len(specs))]
    print("ready", flush=True)
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for bus in buses:
        bus.shutdown()
    for lines in got:
        for line in lines:
            print(line, flush=True)
    short = [i for i, lines in enumerate(got) if len(lines) < specs[i].get("count", 1)]
    if short:
        print(f"timeout: readers {short} got fewer messages than expected", file=sys.stderr)
    return 1 if short else 0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("cmd", choices=["recv", "send", "readers"])
    ap.add_argument("--specs", default="[]")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--count", type=int, default=1)
    ap.add_argument("--filters", default=None)
    ap.add_argument("--frames", default="[]")
    ap.add_argument("--own", action="store_true")
    ap.add_argument("--fd", action="store_true")
    ap.add_argument("--errors", action="store_true", help="receive error frames")
    ap.add_argument("--join", action="store_true")
    # only a bound for failures: under CPU emulation starting the other readers alone takes ~5 s each
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args()

    if args.cmd == "readers":
        return readers(json.loads(args.specs), args.timeout)
    with open_bus(vars(args)) as bus:
        if args.cmd == "recv":
            print("ready", flush=True)
            for _ in range(args.count):
                msg = bus.recv(args.timeout)
                if msg is None:
                    print("timeout", file=sys.stderr)
                    return 1
                print(message_json(msg), flush=True)
            return 0
        frames = json.loads(args.frames)
        for frame in frames:
            bus.send(to_message(frame))
        if args.own:
            for _ in frames:
                msg = bus.recv(args.timeout)
                if msg is None:
                    print("timeout waiting for own message", file=sys.stderr)
                    return 1
                print(message_json(msg), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
