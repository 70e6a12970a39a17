"""diagnostic_msgs/DiagnosticArray: each status a text log at <topic>/<status name>, at its
level, and the level as a scalar (when an ECU's status turned to ERROR, on a plot)."""
from __future__ import annotations

import rerun as rr

from .registry import Context, logger, require

# DiagnosticStatus levels: OK 0, WARN 1, ERROR 2, STALE 3 (no update from its source)
LEVELS: dict[int, str] = {0: "INFO", 1: "WARN", 2: "ERROR", 3: "WARN"}  # Rerun's TextLogLevel names
STALE = 3


def status_text(status) -> str:
    """'[stale] message (hardware_id) key=value, ...' as far as the status has them."""
    text = ("[stale] " if status.level == STALE else "") + status.message
    if status.hardware_id:
        text += f" ({status.hardware_id})"
    if status.values:
        text += " " + ", ".join(f"{kv.key}={kv.value}" for kv in status.values)
    return text


MAX_STATUSES = 1000  # a message with more is refused: each status is an entity of its own
TEXTS_KEPT = 10_000  # statuses whose last text is remembered (hashed), over all messages


@logger("diagnostic_msgs/msg/DiagnosticArray")
def log_diagnostic_array(ctx: Context, path: str, msg) -> None:
    """Each status's level every time; its text when it changed (diagnostic_updater republishes
    unchanged statuses every second: an aggregator's hundreds would fill the log with repeats)."""
    require(len(msg.status) <= MAX_STATUSES, f"{len(msg.status)} statuses: more than {MAX_STATUSES}")
    for status in msg.status:
        entity = f"{path}/{rr.escape_entity_path_part(status.name or '(unnamed)')}"
        text, level = status_text(status), LEVELS.get(status.level, f"LEVEL {status.level}")
        if ctx.texts.get(entity) != (said := hash((text, level))):
            if len(ctx.texts) >= TEXTS_KEPT:
                ctx.texts.clear()  # each status's text is logged once more, then known again
            ctx.texts[entity] = said
            rr.log(entity, rr.TextLog(text, level=level))
        ctx.scalar(f"{entity}/level", status.level)
