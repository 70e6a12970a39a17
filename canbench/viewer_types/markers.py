"""visualization_msgs/Marker and MarkerArray: each marker at <topic>/<ns>/<id>, its pose
a Transform3D there, its shape in the pose's coordinates by marker type; DELETE clears
that marker, DELETEALL every marker of its ns (of the topic when it has none). A MarkerArray
draws every marker it can and counts the array once for those it cannot (a mesh). A marker with a lifetime is cleared at
its receive time + lifetime unless a newer one of that ns/id came first (as RViz does):
the Clear is logged at that time once a later sample, the viewer's idle tick or the end
shows it is due (expire)."""
from __future__ import annotations

import numpy as np
import rerun as rr

from .registry import Context, header_stamp, logger

ARROW, CUBE, SPHERE, CYLINDER, LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, POINTS, TEXT_VIEW_FACING, \
    MESH_RESOURCE, TRIANGLE_LIST, ARROW_STRIP = range(13)
ADD, DELETE, DELETEALL = 0, 2, 3  # MODIFY == ADD


def rgba(c) -> list[int]:
    return [round(min(max(v, 0.0), 1.0) * 255) for v in (c.r, c.g, c.b, c.a)]


def shape(m):
    """The Rerun archetype drawing one marker in its own coordinates."""
    half = [m.scale.x / 2, m.scale.y / 2, m.scale.z / 2]
    pts = np.array([[p.x, p.y, p.z] for p in m.points], dtype=np.float64).reshape(-1, 3)
    colors = [rgba(c) for c in m.colors] if len(m.colors) == len(m.points) and m.colors else [rgba(m.color)]
    if m.type == ARROW:
        if len(pts) >= 2:  # start and end; scale.x shaft diameter
            return rr.Arrows3D(origins=[pts[0]], vectors=[pts[1] - pts[0]], radii=m.scale.x / 2, colors=colors[:1])
        return rr.Arrows3D(vectors=[[m.scale.x, 0, 0]], radii=m.scale.y / 2, colors=colors[:1])  # along x
    if m.type == CUBE:
        return rr.Boxes3D(half_sizes=[half], colors=colors[:1], fill_mode="solid")
    if m.type == SPHERE:
        return rr.Ellipsoids3D(half_sizes=[half], colors=colors[:1], fill_mode="solid")
    if m.type == CYLINDER:  # scale.x, scale.y diameters, scale.z height; Rerun's cylinders are round
        return rr.Cylinders3D(lengths=[m.scale.z], radii=[m.scale.x / 2], colors=colors[:1], fill_mode="solid")
    if m.type == LINE_STRIP:
        if len(colors) > 1:  # a colour per point, as RViz blends them: a strip per segment in its first point's
            return rr.LineStrips3D(np.stack([pts[:-1], pts[1:]], axis=1), radii=m.scale.x / 2, colors=colors[:-1])
        return rr.LineStrips3D([pts], radii=m.scale.x / 2, colors=colors[:1])
    if m.type == LINE_LIST:
        return rr.LineStrips3D(pts[: len(pts) // 2 * 2].reshape(-1, 2, 3), radii=m.scale.x / 2,
                               colors=colors[::2] if len(colors) > 1 else colors)
    if m.type == CUBE_LIST:
        return rr.Boxes3D(centers=pts, half_sizes=[half] * len(pts), colors=colors, fill_mode="solid")
    if m.type == SPHERE_LIST:
        return rr.Ellipsoids3D(centers=pts, half_sizes=[half] * len(pts), colors=colors, fill_mode="solid")
    if m.type == POINTS:
        return rr.Points3D(pts, radii=m.scale.x / 2, colors=colors)
    if m.type == TEXT_VIEW_FACING:  # scale.z the text height
        return rr.Points3D([[0, 0, 0]], labels=[m.text], radii=m.scale.z / 10, colors=colors[:1], show_labels=True)
    if m.type == TRIANGLE_LIST:  # scaled, as RViz's TriangleListMarker does; a partial triangle RViz refuses
        if len(pts) % 3:
            raise ValueError(f"marker {m.ns}/{m.id}: TRIANGLE_LIST of {len(pts)} points, not a multiple of 3")
        scaled = pts * [m.scale.x, m.scale.y, m.scale.z]
        return rr.Mesh3D(vertex_positions=scaled, triangle_indices=np.arange(len(pts)).reshape(-1, 3),
                         vertex_colors=colors * (len(pts) if len(colors) == 1 else 1) if len(pts) else None)
    if m.type == ARROW_STRIP:
        return rr.Arrows3D(origins=pts[:-1], vectors=np.diff(pts, axis=0), radii=m.scale.x / 2, colors=colors[:1])
    if m.type == MESH_RESOURCE:
        raise ValueError(f"marker {m.ns}/{m.id}: MESH_RESOURCE ({m.mesh_resource!r}) is not shown")
    raise ValueError(f"marker {m.ns}/{m.id}: unknown marker type {m.type}")


def expire(ctx: Context, until_ns: int | None = None) -> None:
    """Clear every marker whose lifetime ended by until_ns (None: all still running, at the
    end), at the time it ended; the timeline is left at the current sample's time."""
    due = [(t, e) for e, t in ctx.expiries.items() if until_ns is None or t <= until_ns]
    if due:
        rr.disable_timeline("header_stamp")  # a lifetime runs in receive time: its end has no source stamp
    for t_ns, entity in sorted(due):
        del ctx.expiries[entity]
        rr.set_time("time", timestamp=np.datetime64(t_ns, "ns"))
        rr.log(entity, rr.Clear(recursive=True))
    if due:
        rr.set_time("time", timestamp=np.datetime64(ctx.t_ns, "ns"))


def log_one(ctx: Context, path: str, m) -> None:
    if m.action == DELETEALL:  # of the marker's ns when it has one, else of the topic (Marker.msg, RViz)
        scope = f"{path}/{rr.escape_entity_path_part(m.ns)}" if m.ns else path
        for entity in [e for e in ctx.expiries if e.startswith(scope + "/")]:
            del ctx.expiries[entity]
        rr.log(scope, rr.Clear(recursive=True))
        return
    # one entity part per ns, whatever it holds: ns 'arm/left' nested under 'arm' would be cleared
    # by DELETEALL of 'arm' (RViz's namespaces are flat)
    entity = f"{path}/{rr.escape_entity_path_part(m.ns or '_')}/{m.id}"
    if m.action == DELETE:
        ctx.expiries.pop(entity, None)
        rr.log(entity, rr.Clear(recursive=True))
        return
    if m.action != ADD:
        raise ValueError(f"marker {m.ns}/{m.id}: unknown action {m.action}")
    archetype = shape(m)
    lifetime_ns = m.lifetime.sec * 1_000_000_000 + m.lifetime.nanosec
    if lifetime_ns > 0:
        ctx.expiries[entity] = ctx.t_ns + lifetime_ns
    else:  # 0: forever, also for a marker that had a lifetime before
        ctx.expiries.pop(entity, None)
    ctx.pose(entity, m.pose.position, m.pose.orientation, m.header.frame_id)
    rr.log(f"{entity}/shape", archetype, *([rr.CoordinateFrame(entity)] if m.header.frame_id else []))


@logger("visualization_msgs/msg/Marker")
def log_marker(ctx: Context, path: str, msg) -> None:
    expire(ctx, ctx.t_ns)
    header_stamp(msg.header.stamp)  # expire took it off that timeline
    log_one(ctx, path, msg)


@logger("visualization_msgs/msg/MarkerArray")
def log_marker_array(ctx: Context, path: str, msg) -> None:
    expire(ctx, ctx.t_ns)
    refused = []
    for m in msg.markers:  # one the viewer cannot draw (a mesh) leaves the others drawn, as in RViz
        header_stamp(m.header.stamp)
        try:
            log_one(ctx, path, m)
        except ValueError as e:
            refused.append(str(e))
    if refused:  # counted for the topic, the first reason said
        raise ValueError(f"{len(refused)} of {len(msg.markers)} markers not shown: {refused[0]}")
