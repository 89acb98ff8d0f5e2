"""Task recordings as MCAP files that rosbag2 and Foxglove read (no rclpy).

:class:`McapRecorder` writes already-serialized (CDR) ROS 2 messages with the ``ros2msg``
schema encoding (the concatenated ``.msg`` definitions, as rosbag2 writes them), built from
the installed interface files by :func:`message_definition`. :func:`read_recording` reads a
file back into plain Python objects with ``mcap-ros2-support``'s stock decoder (every
recorded type has a valid .msg name: the task's feedback is recorded as
``hyperarm_interfaces/msg/TaskFeedback``; recordings made before that, with the action's
``RunTask_FeedbackMessage`` channel, are read with a renaming decoder).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Callable, Iterator

from mcap.writer import CompressionType, Writer

__all__ = ["message_definition", "McapRecorder", "read_recording", "RECORDED_TOPICS",
           "TASK_FEEDBACK"]

#: the task node's feedback on a plain topic (hyperarm_interfaces/msg/TaskFeedback): the
#: action's own feedback topic has the type RunTask_FeedbackMessage, which stock MCAP
#: readers refuse ("'RunTask_FeedbackMessage' is an invalid message name")
TASK_FEEDBACK = "task_feedback"

# topic (relative to the namespace) -> ROS type, as recorded for a task run
RECORDED_TOPICS = {
    "joint_states": "sensor_msgs/msg/JointState",
    "joint_command": "sensor_msgs/msg/JointState",
    "hybrid_goal": "hyperarm_interfaces/msg/HybridGoal",
    "ee_wrench": "geometry_msgs/msg/WrenchStamped",
    "detections": "hyperarm_interfaces/msg/Detections",
    TASK_FEEDBACK: "hyperarm_interfaces/msg/TaskFeedback",
}

_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
               "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"}
_SEP = "=" * 80


def _share(package: str) -> Path:
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory(package))


def _action_part(package: str, action: str, part: int) -> str:
    text = (_share(package) / "action" / f"{action}.action").read_text()
    return re.split(r"^---\s*$", text, flags=re.M)[part]


def _text(full: str, share: Callable[[str], Path]) -> str:
    pkg, kind, name = full.split("/")
    if kind == "action":
        action, _, suffix = name.rpartition("_")
        if suffix == "FeedbackMessage":
            return f"unique_identifier_msgs/UUID goal_id\n{pkg}/{action}_Feedback feedback\n"
        part = {"Goal": 0, "Result": 1, "Feedback": 2}[suffix]
        return _action_part(pkg, action, part)
    return (share(pkg) / kind / f"{name}.msg").read_text()


def _deps(text: str, pkg: str) -> list[str]:
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        base = re.split(r"[\[<]", line.split()[0])[0]
        if base in _PRIMITIVES or "=" in line.split()[0]:
            continue
        if "/" not in base:
            base = f"{pkg}/{base}"
        p, n = base.split("/")[0], base.split("/")[-1]
        kind = "action" if n.startswith(tuple(_actions(p))) and "_" in n else "msg"
        out.append(f"{p}/{kind}/{n}")
    return out


def _actions(pkg: str) -> list[str]:
    try:
        return [f.stem + "_" for f in (_share(pkg) / "action").glob("*.action")]
    except (LookupError, ValueError, OSError):
        return []


def message_definition(full_type: str, share: Callable[[str], Path] = _share) -> str:
    """The ``ros2msg`` definition of ``pkg/msg/Name`` (or ``pkg/action/Name_Suffix``)
    with every dependency appended, the format rosbag2 stores in MCAP schemas."""
    main = _text(full_type, share)
    parts, seen = [main.rstrip("\n")], {full_type}
    todo = _deps(main, full_type.split("/")[0])
    while todo:
        dep = todo.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        text = _text(dep, share)
        pkg, _, name = dep.split("/")
        parts.append(f"{_SEP}\nMSG: {pkg}/{name}\n{text.rstrip(chr(10))}")
        todo.extend(_deps(text, pkg))
    return "\n".join(parts) + "\n"


class McapRecorder:
    """Writes serialized messages to an MCAP file (zstd chunks). Thread-compatible: the
    caller serializes calls to :meth:`write`."""

    def __init__(self, path: str | Path, topics: dict[str, str]) -> None:
        self.path = Path(path)
        self._fh = open(self.path, "wb")
        self._writer = Writer(self._fh, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="hyperarm_tasks")
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        for topic, full in topics.items():
            schema = self._writer.register_schema(
                name=full, encoding="ros2msg", data=message_definition(full).encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema)
            self.counts[topic] = 0
        self._closed = False

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None):
        if self._closed:
            return
        self._writer.add_message(channel_id=self._channels[topic], log_time=log_time_ns,
                                 publish_time=publish_time_ns or log_time_ns, data=data,
                                 sequence=self.counts[topic])
        self.counts[topic] += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.finish()
            self._fh.close()


def _decoder_factory():
    """mcap-ros2-support's decoder, also for the action feedback channel of older
    recordings: ``RunTask_FeedbackMessage`` is not a valid .msg name to its parser, so such a
    schema is decoded under a name without the underscores (the CDR layout does not depend
    on it). Every channel recorded now decodes with the stock decoder unchanged."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    class Factory(DecoderFactory):
        def decoder_for(self, message_encoding, schema):
            if schema is not None and "_" in schema.name.rsplit("/", 1)[-1]:
                text = schema.data.decode()
                for old in set(re.findall(r"\b[A-Z][A-Za-z0-9]*_[A-Za-z0-9_]+\b", text)
                               + [schema.name.rsplit("/", 1)[-1]]):
                    text = text.replace(old, old.replace("_", ""))
                pkg, _, name = schema.name.split("/")
                schema = Schema(id=schema.id, name=f"{pkg}/msg/{name.replace('_', '')}",
                                encoding=schema.encoding, data=text.encode())
            return super().decoder_for(message_encoding, schema)

    return Factory()


def read_recording(path: str | Path) -> Iterator[tuple[str, float, object]]:
    """(topic, log time s, decoded message) for every message of an MCAP file."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[_decoder_factory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            yield channel.topic, message.log_time * 1e-9, decoded
