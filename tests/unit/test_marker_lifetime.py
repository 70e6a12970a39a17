"""visualization_msgs/Marker.lifetime: a marker is cleared at its receive time + lifetime
(the Clear logged at exactly that time on the marker's entity), unless a newer marker of
the same ns/id came first or it was deleted; lifetime 0 lives forever."""
from __future__ import annotations

import pytest

from canbench import ros2_msgs as m

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from rerun.chunk import RrdReader  # noqa: E402

from canbench.viewer_types import LOGGERS, Context  # noqa: E402

S = 1_000_000_000
T0 = 1_700_000_000 * S  # receive times as the viewer stamps them (ns since the epoch)


def marker(ident: int, lifetime_ns: int = 0, action: int = 0) -> m.Marker:
    return m.Marker(header=m.Header(frame_id="base_link"), ns="obstacles", id=ident, type=1, action=action,
                    scale=m.Vector3(1, 1, 1), color=m.ColorRGBA(1, 0, 0, 1),
                    lifetime=m.Duration(sec=lifetime_ns // S, nanosec=lifetime_ns % S))


def clears(path, messages: list[tuple[int, m.Marker]], end: bool = False) -> dict[str, list[int]]:
    """Log (receive time, marker) pairs as the viewer does; entity -> times (ns) of its Clears."""
    rec = rr.RecordingStream("canbench-test-lifetime")
    rec.save(str(path))
    ctx = Context()
    with rec:
        for t_ns, msg in messages:
            rr.set_time("time", timestamp=t_ns / 1e9)
            ctx.t_ns = t_ns
            LOGGERS["visualization_msgs/msg/Marker"](ctx, "ros2/m", m.Marker.deserialize(msg.serialize()))
        if end:
            from canbench.viewer_types.markers import expire
            expire(ctx)
    rec.flush()
    rec.disconnect()
    out: dict[str, list[int]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        if "Clear:is_recursive" in batch.schema.names:
            times = batch.column("time").cast("int64").to_pylist()
            out.setdefault(str(chunk.entity_path), []).extend(times)
    return out


def test_marker_is_cleared_when_its_lifetime_ends(tmp_path):
    got = clears(tmp_path / "a.rrd", [(T0, marker(1, lifetime_ns=S // 2)), (T0, marker(2)),
                                      (T0 + 2 * S, marker(3))])
    assert got == {"/ros2/m/obstacles/1": [T0 + S // 2]}  # 0.5 s after it came; lifetime 0: kept


def test_refreshed_marker_lives_on_and_delete_cancels(tmp_path):
    got = clears(tmp_path / "b.rrd", [
        (T0, marker(1, lifetime_ns=S)), (T0, marker(2, lifetime_ns=S)), (T0, marker(4, lifetime_ns=S)),
        (T0 + S // 5, marker(2, action=2)),  # deleted before it expired
        (T0 + S // 2, marker(4)),  # replaced by one without a lifetime
        (T0 + 8 * S // 10, marker(1, lifetime_ns=S)),  # refreshed in time: cleared at the end, 1 s later
    ], end=True)
    assert got == {"/ros2/m/obstacles/1": [T0 + 18 * S // 10], "/ros2/m/obstacles/2": [T0 + S // 5]}
