"""The viewer's loggers driven without Zenoh: ROS 2 messages (CDR bytes, or a ros2_msgs message to
serialize) decoded and logged into an .rrd, read back as columns, for the viewer's tests."""
from __future__ import annotations

import rerun as rr

from canbench import ros2_msgs as m
from canbench.viewer import read_rrd_columns
from canbench.viewer_types import LOGGERS, Context


def logged(tmp_path, messages: list[tuple[str, str, object]]) -> tuple[dict, list[str]]:
    """(type, topic path, CDR payload or message) decoded and logged into an .rrd: its columns, and
    the errors the viewer would count (one per message a logger refused)."""
    path = tmp_path / "t.rrd"
    rec = rr.RecordingStream("canbench-test-logged")
    rec.save(str(path))
    ctx, errors = Context(), []
    with rec:
        for i, (type_name, topic, payload) in enumerate(messages):
            rr.set_time("time", timestamp=1_700_000_000 + i)
            cdr = payload if isinstance(payload, bytes) else payload.serialize()  # type: ignore[attr-defined]
            try:
                LOGGERS[type_name](ctx, topic, m.decode(type_name, cdr))
            except ValueError as e:
                errors.append(str(e))
    rec.flush()
    rec.disconnect()
    return read_rrd_columns(path), errors
