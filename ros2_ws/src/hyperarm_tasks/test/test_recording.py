"""Task recordings decode with mcap-ros2-support's stock DecoderFactory, every channel (issue
24, item 6: the action feedback channel, type RunTask_FeedbackMessage, was refused as "an
invalid message name"; the feedback is now recorded as hyperarm_interfaces/msg/TaskFeedback)."""
from __future__ import annotations

import importlib

import pytest

from hyperarm_tasks.recording import RECORDED_TOPICS, TASK_FEEDBACK, McapRecorder

pytestmark = [pytest.mark.node]


def _cls(full: str):
    pkg, kind, name = full.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def test_every_recorded_channel_decodes_with_the_stock_decoder(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rclpy.serialization import serialize_message

    path = tmp_path / "run.mcap"
    rec = McapRecorder(path, {f"/hyperarm/{t}": full for t, full in RECORDED_TOPICS.items()})
    sent = {}
    for k, (topic, full) in enumerate(RECORDED_TOPICS.items()):
        msg = _cls(full)()
        if topic == TASK_FEEDBACK:
            msg.task, msg.stage, msg.phase, msg.depth = "block_transfer", "insert", "dithering", 0.012
            msg.waypoint.point.z = -0.12
            msg.goal_id.uuid = list(range(16))
        sent[f"/hyperarm/{topic}"] = msg
        rec.write(f"/hyperarm/{topic}", serialize_message(msg), 1_000_000 * (k + 1))
    rec.close()
    got = {}
    with open(path, "rb") as fh:
        for schema, channel, _m, decoded in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic] = (schema.name, decoded)
    assert set(got) == set(sent)
    name, fb = got[f"/hyperarm/{TASK_FEEDBACK}"]
    assert name == "hyperarm_interfaces/msg/TaskFeedback"
    assert (fb.task, fb.stage, fb.phase) == ("block_transfer", "insert", "dithering")
    assert fb.depth == pytest.approx(0.012) and fb.waypoint.point.z == pytest.approx(-0.12)
    assert list(fb.goal_id.uuid) == list(range(16))
