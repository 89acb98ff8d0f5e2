"""task_recorder: records a task run to an MCAP file (rosbag2- and Foxglove-readable).

    task_recorder --ros-args -p output:=run.mcap

Topics (namespace-relative): joint_states, joint_command, hybrid_goal, ee_wrench,
detections and the task's action feedback (run_task/_action/feedback), as serialized CDR
(no decode/re-encode). The file is finished on SIGINT/SIGTERM. Plot it with
``plot_task run.mcap``.
"""
from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import QoSProfile

from hyperarm_description import contract
from hyperarm_description.params import NonEmpty, ParamSpec, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node

from .recording import RECORDED_TOPICS, McapRecorder


#: Every parameter of the node (also its --help): name -> (default, description, check).
PARAMETERS: ParamSpec = {"output": ("task.mcap", "MCAP file to write (overwritten)", NonEmpty())}


def _type(full: str):
    import importlib
    pkg, kind, name = full.split("/")
    if kind == "action":
        action, _, suffix = name.rpartition("_")
        return getattr(getattr(importlib.import_module(f"{pkg}.action"), action).Impl, suffix)
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


class TaskRecorder(Node):
    def __init__(self) -> None:
        super().__init__("task_recorder", namespace=contract.DEFAULT_NAMESPACE)
        p = declare_parameters(self, PARAMETERS)
        # channels under the full names (/hyperarm/joint_states, ...), as rosbag2 records them
        topics = {self.resolve_topic_name(t): full for t, full in RECORDED_TOPICS.items()}
        try:
            self._rec = McapRecorder(p["output"], topics)
        except OSError as exc:
            raise SystemExit(f"task_recorder: cannot write {p['output']}: {exc}") from None
        for topic, full in RECORDED_TOPICS.items():
            qos = qos_for(topic) if topic in contract.QOS else QoSProfile(depth=50)
            self.create_subscription(_type(full), topic,
                                     self._writer(self.resolve_topic_name(topic)), qos, raw=True)
        self.get_logger().info(f"recording {', '.join(topics)} to {p['output']}")

    def _writer(self, topic: str):
        def write(data: bytes) -> None:
            self._rec.write(topic, data, self.get_clock().now().nanoseconds)
        return write

    def destroy_node(self) -> None:
        self._rec.close()
        counts = ", ".join(f"{t} {n}" for t, n in self._rec.counts.items())
        print(f"task_recorder: wrote {self._rec.path} ({counts})", flush=True)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(TaskRecorder, args, parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
