"""e2e: the installed marker_detector starts, reports in its diagnostics that it waits for a
CameraInfo, and stops on SIGTERM (exit 0) and SIGINT (the launch fixture's check); a bad
marker map ends it with exit 1 and a line naming the field."""
from __future__ import annotations

import signal
import time

import pytest

pytestmark = [pytest.mark.e2e]


def test_starts_waits_for_camera_info_and_stops_cleanly(launch, rclpy_context, executor,
                                                         wait_for):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    from hyperarm_description import contract
    from hyperarm_description.qos import qos_for

    node = launch("hyperarm_perception", "marker_detector",
                  params={"diagnostics_period": 0.2})
    other = launch("hyperarm_perception", "marker_detector",
                   params={"diagnostics_period": 0.2}, namespace="/second")
    probe = rclpy.create_node("marker_e2e_probe", context=rclpy_context)
    executor.add_node(probe)
    seen = []
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: seen.extend(s.message for s in m.status
                                                    if s.name == "marker_detector"),
                              qos_for(contract.DIAGNOSTICS))
    wait_for(lambda: seen, 30.0, what=lambda: f"diagnostics\n{node.output()}")
    assert "waiting for a valid CameraInfo on camera/camera_info" in seen[-1]
    other.proc.send_signal(signal.SIGTERM)
    assert other.proc.wait(timeout=10.0) == 0, other.output()
    assert node.proc.poll() is None          # SIGINT at teardown, checked by the fixture


def test_bad_marker_map_exits_with_the_field(launch, tmp_path):
    bad = tmp_path / "markers.yaml"
    bad.write_text("schema_version: 1\ndictionary: DICT_APRILTAG_36h11\n"
                   "markers: [{id: 0, object: block, size: -0.03}]\n")
    proc = launch("hyperarm_perception", "marker_detector", params={"marker_map": str(bad)})
    deadline = time.monotonic() + 30.0
    while proc.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.proc.returncode == 1, proc.output()
    assert "marker_detector: markers.yaml: markers[0] (id 0).size" in proc.output()
