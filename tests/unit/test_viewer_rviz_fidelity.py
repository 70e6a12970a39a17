"""What the viewer draws as RViz and candump do, found against their sources: a ros2_socketcan
error frame is no message of the DBC (it was decoded as its error class's id), a triangle list is
scaled (rviz_default_plugins' TriangleListMarker) and a partial triangle refused, a line strip keeps
its points' colours, an occupancy grid's plane lies at its origin on any ROS domain (its frame was
prefixed with the domain twice), uyvy and yuyv are the image encodings' names since Iron."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canbench import ros2_msgs as m

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from rrd_logged import logged  # noqa: E402

from canbench.dbc import load_dbc  # noqa: E402
from canbench.viewer_types import LOGGERS, Context, registry  # noqa: E402
from canbench.viewer_types import images as images_mod  # noqa: E402
from canbench.viewer_types.markers import LINE_STRIP, TRIANGLE_LIST, shape  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
RED, GREEN, BLUE = m.ColorRGBA(1, 0, 0, 1), m.ColorRGBA(0, 1, 0, 1), m.ColorRGBA(0, 0, 1, 1)


def test_a_can_error_frame_is_said_as_one_not_decoded_as_its_class_id(tmp_path, monkeypatch):
    # ros2_socketcan: is_error, the id the error class (0x100: CAN_ERR_RESTARTED); powertrain.dbc has a 0x100
    frame = m.CanFrame(header=m.Header(frame_id="can"), id=0x100, is_error=True, dlc=8, data=bytes(8))
    seen = []
    original = LOGGERS["can_msgs/msg/Frame"]

    def with_dbc(ctx, path, msg):
        ctx.dbc = load_dbc(REPO / "scenarios" / "dbc" / "powertrain.dbc")
        seen.append(ctx)
        original(ctx, path, msg)
    monkeypatch.setitem(LOGGERS, "can_msgs/msg/Frame", with_dbc)
    columns, errors = logged(tmp_path, [("can_msgs/msg/Frame", "ros2/can/vcan0", frame)])
    assert not errors
    assert sorted(e for e in columns if e.startswith("/ros2/")) == ["/ros2/can/vcan0/error"]
    assert columns["/ros2/can/vcan0/error"]["TextLog:text"] == [["20000100#0000000000000000 (error class 100)"]]


def marker(kind: int, points, colors=(), scale=(1.0, 1.0, 1.0)) -> m.Marker:
    return m.Marker(type=kind, scale=m.Vector3(*scale), color=RED, points=[m.Point(*p) for p in points],
                    colors=list(colors))


def test_a_triangle_list_is_scaled_as_rviz_scales_it_and_a_partial_triangle_is_refused():
    mesh = shape(marker(TRIANGLE_LIST, [(0, 0, 0), (1, 0, 0), (0, 1, 0)], scale=(2, 2, 2)))
    assert np.asarray(mesh.vertex_positions.as_arrow_array().to_pylist()).tolist() == [
        [0, 0, 0], [2, 0, 0], [0, 2, 0]]
    with pytest.raises(ValueError, match="TRIANGLE_LIST of 4 points, not a multiple of 3"):
        shape(marker(TRIANGLE_LIST, [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]))


def test_a_line_strip_keeps_a_colour_per_point():
    strips = shape(marker(LINE_STRIP, [(0, 0, 0), (1, 0, 0), (2, 0, 0)], colors=[RED, GREEN, BLUE]))
    assert strips.colors.as_arrow_array().to_pylist() == [0xFF0000FF, 0x00FF00FF]  # each segment its first point's
    assert len(strips.strips.as_arrow_array().to_pylist()) == 2
    one = shape(marker(LINE_STRIP, [(0, 0, 0), (1, 0, 0), (2, 0, 0)]))
    assert len(one.strips.as_arrow_array().to_pylist()) == 1


@pytest.mark.parametrize("domain", ["", "domain7"])
def test_an_occupancy_grids_plane_lies_in_the_frame_its_origin_names_on_any_domain(domain, monkeypatch):
    logged_now: list = []
    monkeypatch.setattr(registry.rr, "log", lambda path, *archetypes, **kw: logged_now.append((path, archetypes)))
    grid = m.OccupancyGrid(header=m.Header(frame_id="map"),
                           info=m.MapMetaData(resolution=0.5, width=2, height=2, origin=m.Pose()),
                           data=[0, 100, -1, 50])
    ctx = Context()
    ctx.domain = domain
    path = "ros2/" + (f"{domain}/" if domain else "") + "map"
    images_mod.log_occupancy_grid(ctx, path, m.decode("nav_msgs/msg/OccupancyGrid", grid.serialize()))
    child = next(a.child_frame.as_arrow_array().to_pylist()[0] for p, archs in logged_now for a in archs
                 if p == path and isinstance(a, rr.Transform3D))
    plane = next(a.frame.as_arrow_array().to_pylist()[0] for p, archs in logged_now for a in archs
                 if p == f"{path}/plane" and isinstance(a, rr.CoordinateFrame))
    assert child == plane == path


@pytest.mark.parametrize("encoding", ["uyvy", "yuyv"])
def test_uyvy_and_yuyv_are_the_yuv422_encodings_of_their_names(encoding):
    pixels = bytes([10, 20, 30, 40, 50, 60, 70, 80])  # two rows of two pixels: two bytes a pixel
    msg = m.Image(height=2, width=2, encoding=encoding, step=4, data=pixels)
    array, shown, _ = images_mod.image_array(msg)
    assert shown == rr.PixelFormat.YUY2
    if encoding == "uyvy":  # U Y0 V Y1 reordered to Y0 U Y1 V
        assert array.reshape(-1).tolist() == [20, 10, 40, 30, 60, 50, 80, 70]
    else:
        assert array.reshape(-1).tolist() == list(pixels)
