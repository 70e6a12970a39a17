"""A bench error from per-reader stamps names its cause: round-trip runs on a ucan build older
than one stamp per frame had every bridge stamp differ from candump's (688 of 688, up to 503 us)
and a few CAN -> Zenoh latencies below zero; the error must say so, not only "stamps are wrong"."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from canbench import oracle, validity, wire

pytestmark = pytest.mark.unit


def _run(bridge_offset_ns: int) -> SimpleNamespace:
    f = wire.Frame(0x1A0, 8, bytes(8), False)
    on_bus = [oracle.Observed(f, 1_000_000, 0, line=1)]  # candump's stamp
    # zn-capture received it 40 us before candump's stamp; the bridge stamped it bridge_offset_ns off candump
    on_zenoh = [oracle.Observed(f, 960_000, 0, key="vehicle/can/rx", seq=0, bridge_rx_ns=1_000_000 + bridge_offset_ns)]
    return SimpleNamespace(buses=[SimpleNamespace(bus="vcan0", comparison=oracle.compare(on_bus, on_zenoh),
                                                  zenoh_to_can=None, round_trip=None)])


def test_per_reader_stamps_are_named_as_the_cause():
    errors = validity.bench_errors(_run(-500_000))
    assert len(errors) == 1 and "1 of 1 matched frames arrived before they were sent" in errors[0]
    assert "different stamps" in errors[0] and "up to 500.0 us" in errors[0] and "rebuild ucan" in errors[0]


def test_one_stamp_per_frame_names_no_such_cause():
    errors = validity.bench_errors(_run(0))
    assert len(errors) == 1 and "different stamps" not in errors[0]
