"""Differential check: the same frame sequences (tests/bus/differential.py) on
the userspace hub and on real kernel vcan must give every reader the same
frames, byte for byte, in the same order per sender. Kernel vcan here natively
when the kernel has it, else Debian's kernel in QEMU (ucan/vm/vcan-vm).

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


def per_sender(result: dict) -> dict:
    return {reader: {s: [r for r in records if sender_of(r["can_id"]) == s] for s in ("main", "fd", "quiet")}
            for reader, records in result.items()}


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
    assert set(ours) == set(kernel_result)
    assert sum(len(v) for v in kernel_result.values()) > 50  # the probe really exercised the bus
    assert differences(ours, kernel_result) == []


def test_broken_emulation_is_caught_and_named(kernel_result, tmp_path):
    """Filters that ignore the RTR bit (UCAN_HUB_TEST_FAULT) must show, naming readers and frames."""
    broken = userspace_result(tmp_path, "ignore-rtr-filter")
    diffs = differences(broken, kernel_result)
    assert any("reader rtr_only_123" in d and "00000123" in d for d in diffs), diffs
    assert any("reader sff_only_123" in d for d in diffs), diffs
