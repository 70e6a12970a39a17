"""Differential check: the same frame sequences (tests/bus/differential.py) on
the userspace hub and on real kernel vcan must give every reader the same
frames, byte for byte, in the same order per sender, and stamps by the
kernel's rules: every reader of a frame sees one stamp, stamps never decrease
on an interface, a frame is stamped after it was sent and before any reader
got it. Kernel vcan here natively when the kernel has it, else Debian's
kernel in QEMU (ucan/vm/vcan-vm).

Known, deliberate divergence (docs/userspace-bus.md): frames written on
different sockets are ordered per socket by the hub, while kernel vcan orders
them by send() call; so order is compared per sender."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import differential  # importable: pytest imports a test with its own folder first on the path
import pytest
from conftest import KERNEL_VCAN, REPO, Bus, ensure_kernel_vcan

PROBE = Path(__file__).with_name("differential.py")

pytestmark = pytest.mark.bus


def sender_of(can_id_hex: str) -> str:
    can_id = int(can_id_hex, 16)
    for sender, _, data in differential.SENDS:
        if int.from_bytes(data[:4], "little") == can_id:
            return sender
    return "?"


def without_stamps(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in differential.STAMP_KEYS}


def per_sender(result: dict) -> dict:
    return {reader: {s: [without_stamps(r) for r in records if sender_of(r["can_id"]) == s]
                     for s in ("main", "fd", "quiet")}
            for reader, records in result["readers"].items()}


def frame_key(iface: str, frame_hex: str) -> tuple[str, str]:
    """A frame of the probe by its interface, id and DLC (the kernel adds CANFD_FDF to FD flags)."""
    return iface, frame_hex[:10]


def stamp_problems(result: dict) -> list[str]:
    """The kernel's stamp rules, each violation named with its reader and frame."""
    problems = []
    sent = {frame_key(s["iface"], s["bytes"]): s["sent_ns"] for s in result["sends"]}
    stamps_of: dict[tuple[str, str], dict[str, int]] = {}
    for reader, records in sorted(result["readers"].items()):
        last: dict[str, int] = {}
        for r in records:
            frame, stamp = f"{r['iface']} {r['can_id']}", r["stamp_ns"]
            if stamp is None:
                problems.append(f"reader {reader}: {frame} came without SCM_TIMESTAMPNS")
                continue
            key = frame_key(r["iface"], r["bytes"])
            stamps_of.setdefault(key, {})[reader] = stamp
            if stamp > r["received_ns"]:
                problems.append(f"reader {reader}: {frame} stamped {stamp - r['received_ns']} ns after it got it")
            if key in sent and stamp < sent[key]:
                problems.append(f"reader {reader}: {frame} stamped {sent[key] - stamp} ns before it was sent")
            if stamp < last.get(r["iface"], 0):
                problems.append(f"reader {reader}: {frame} stamped {last[r['iface']] - stamp} ns before the "
                                f"frame it got earlier on {r['iface']}")
            last[r["iface"]] = stamp
    for (iface, head), by_reader in sorted(stamps_of.items()):
        if len(set(by_reader.values())) > 1:
            spread = max(by_reader.values()) - min(by_reader.values())
            problems.append(f"{iface} frame {head}: {len(set(by_reader.values()))} different stamps across "
                            f"{len(by_reader)} readers (spread {spread} ns)")
    return problems


def differences(a: dict, b: dict) -> list[str]:
    out = []
    pa, pb = per_sender(a), per_sender(b)
    for reader in sorted(set(pa) | set(pb)):
        for sender in ("main", "fd", "quiet"):
            x, y = pa.get(reader, {}).get(sender), pb.get(reader, {}).get(sender)
            if x != y:
                ids_x = [r["can_id"] for r in x or []]
                ids_y = [r["can_id"] for r in y or []]
                out.append(f"reader {reader}, frames from {sender}: userspace {ids_x} vs kernel {ids_y}"
                           + ("" if ids_x != ids_y else f" (same ids, different bytes/flags: {x} vs {y})"))
    return out


@pytest.fixture(scope="session")
def kernel_result(tmp_path_factory) -> dict:
    if KERNEL_VCAN:
        for name in ("vcan0", "vcan1"):
            ensure_kernel_vcan(name, 72)
        env = {k: v for k, v in os.environ.items() if k != "LD_PRELOAD"}
        return json.loads(subprocess.run([sys.executable, str(PROBE)], env=env, capture_output=True, text=True,
                                         check=True).stdout)
    if os.environ.get("VCANVM") or not (shutil.which("qemu-system-x86_64") and os.path.exists("/bin/busybox")):
        pytest.skip("no kernel vcan here and no QEMU/busybox-static for ucan/vm/vcan-vm")
    out = REPO / "build" / "differential-kernel.json"
    out.parent.mkdir(exist_ok=True)
    rc = subprocess.run([str(REPO / "ucan" / "vm" / "vcan-vm"), "--", "sh", "-c",
                         f"{sys.executable} {PROBE} > {out}"], capture_output=True, text=True, timeout=600)
    assert rc.returncode == 0, rc.stdout[-3000:] + rc.stderr[-3000:]
    return json.loads(out.read_text())


def userspace_result(tmp_path: Path, test_fault: str = "") -> dict:
    bus = Bus("userspace", tmp_path)
    os.environ["UCAN_HUB_TEST_FAULT"] = test_fault
    try:
        bus.start_hub("vcan0", "vcan1")
    finally:
        os.environ.pop("UCAN_HUB_TEST_FAULT")
    try:
        return json.loads(bus.run([sys.executable, str(PROBE)]).stdout)
    finally:
        bus.stop_hub()


def test_userspace_bus_matches_kernel_vcan(kernel_result, tmp_path):
    ours = userspace_result(tmp_path)
    assert set(ours["readers"]) == set(kernel_result["readers"])
    assert sum(len(v) for v in kernel_result["readers"].values()) > 50  # the probe really exercised the bus
    assert differences(ours, kernel_result) == []
    assert stamp_problems(kernel_result) == []  # the rules are the kernel's
    assert stamp_problems(ours) == []


def test_stamp_rules_catch_a_stamp_per_reader(kernel_result):
    """A bus that stamps each reader's copy when it delivers it (as the hub did) is caught."""
    shifted = json.loads(json.dumps(kernel_result))
    for i, record in enumerate(shifted["readers"]["fd"]):
        record["stamp_ns"] += 1000 + i
    problems = stamp_problems(shifted)
    assert any("different stamps" in p for p in problems), problems


def test_broken_emulation_is_caught_and_named(kernel_result, tmp_path):
    """Filters that ignore the RTR bit (UCAN_HUB_TEST_FAULT) must show, naming readers and frames."""
    broken = userspace_result(tmp_path, "ignore-rtr-filter")
    diffs = differences(broken, kernel_result)
    assert any("reader rtr_only_123" in d and "00000123" in d for d in diffs), diffs
    assert any("reader sff_only_123" in d for d in diffs), diffs
