"""diagnostic_msgs/DiagnosticArray: each status a text log at <topic>/<status name>, at its
level, and the level as a scalar (when an ECU's status turned to ERROR, on a plot)."""
from __future__ import annotations

import rerun as rr

from .registry import Context, logger

# DiagnosticStatus levels: OK 0, WARN 1, ERROR 2, STALE 3 (no update from its source)
LEVELS = {0: rr.TextLogLevel.INFO, 1: rr.TextLogLevel.WARN, 2: rr.TextLogLevel.ERROR, 3: rr.TextLogLevel.WARN}
STALE = 3


def status_text(status) -> str:
    """'[stale] message (hardware_id) key=value, ...' as far as the status has them."""
    text = ("[stale] " if status.level == STALE else "") + status.message
    if status.hardware_id:
        text += f" ({status.hardware_id})"
    if status.values:
        text += " " + ", ".join(f"{kv.key}={kv.value}" for kv in status.values)
    return text


@logger("diagnostic_msgs/msg/DiagnosticArray")
def log_diagnostic_array(ctx: Context, path: str, msg) -> None:
    for status in msg.status:
        entity = f"{path}/{rr.escape_entity_path_part(status.name or '(unnamed)')}"
        rr.log(entity, rr.TextLog(status_text(status), level=LEVELS.get(status.level, f"LEVEL {status.level}")))
        ctx.scalar(f"{entity}/level", status.level)
