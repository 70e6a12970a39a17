"""canbench.wire against the golden vectors the C unit tests use too."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import wire

VECTORS = Path(__file__).resolve().parents[1] / "data" / "wire_vectors.txt"


def load_vectors():
    for lineno, line in enumerate(VECTORS.read_text().splitlines(), 1):
        if line.strip() and not line.startswith("#"):
            yield pytest.param(line.split(), id=f"{line.split()[0]}:{lineno}")


@pytest.mark.unit
@pytest.mark.parametrize("fields", list(load_vectors()))
def test_golden_vector(fields):
    name, hexbytes, verdict, *rest = fields
    raw = b"" if hexbytes == "-" else bytes.fromhex(hexbytes)
    if verdict == "ok":
        can_id, kind, frame_type, dlc, data = rest
        frame = wire.decode(raw)
        assert frame == wire.Frame(int(can_id, 16), int(dlc), b"" if data == "-" else bytes.fromhex(data),
                                   extended=kind == "e", remote=frame_type == "r")
        assert wire.encode(frame) == raw
    else:
        with pytest.raises(wire.WireError) as err:
            wire.decode(raw)
        assert err.value.reason == rest[0]


@pytest.mark.unit
def test_attachment_round_trip_and_refusals():
    att = wire.encode_attachment(41, [10, 20, 30])
    assert wire.decode_attachment(att) == wire.Attachment(41, (10, 20, 30))
    for bad in (b"", att[:11], att[:-1], b"\x02" + att[1:], att[:1] + b"\x01" + att[2:]):
        with pytest.raises(wire.WireError):
            wire.decode_attachment(bad)


@pytest.mark.unit
def test_batches_and_candump_text():
    frames = [wire.Frame(0x123, 2, b"\xde\xad"), wire.Frame(0x1ABCDEF, 0, extended=True, remote=True)]
    assert wire.decode_batch(b"".join(map(wire.encode, frames))) == frames
    assert [f.candump() for f in frames] == ["vcan0 123#DEAD", "vcan0 01ABCDEF#R"]
    with pytest.raises(wire.WireError):
        wire.decode_batch(b"")
