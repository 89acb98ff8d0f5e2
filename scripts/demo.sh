#!/usr/bin/env bash
# `make demo`: the main job on the mock driver, no hardware.
#
# Starts mock_driver, fk_node and task_node as separate processes (exactly what
# `ros2 run` starts on the robot), then runs task sequences from the shell script and prints
# where the tool went. Everything is stopped with Ctrl-C semantics (SIGINT) at the end.
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
LOGS="$(mktemp -d)"
pids=()
cleanup() {
  # Ctrl-C for every node, then up to 10 s each to exit cleanly; a node that does not is
  # named and killed, so the demo never hangs on its way out.
  for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do
    if ! timeout 10 tail --pid="$pid" -f /dev/null; then
      echo "demo: process $pid did not exit on SIGINT (logs in $LOGS); killing it" >&2
      kill -KILL "$pid" 2>/dev/null || true
    fi
    wait "$pid" 2>/dev/null || true
  done
  # the logs only matter when something failed; keep them then (or with KEEP_LOGS=1)
  if [ "$status" = 0 ] && [ "${KEEP_LOGS:-0}" != 1 ]; then rm -rf "$LOGS"; else
    echo "demo: logs kept in $LOGS" >&2; fi
}
trap 'status=$?; cleanup' EXIT

lib() { echo "$ROOT/ros2_ws/install/$1/lib/$1/$2"; }

echo "== hyperarm demo (ROS_DOMAIN_ID=$ROS_DOMAIN_ID, logs in $LOGS)"
"$(lib hyperarm_description show_description)"
echo
echo "== starting mock_driver, fk_node, task_node"
"$(lib hyperarm_driver mock_driver)" > "$LOGS/mock_driver.log" 2>&1 & pids+=($!)
"$(lib hyperarm_ik fk_node)" > "$LOGS/fk_node.log" 2>&1 & pids+=($!)
"$(lib hyperarm_tasks task_node)" > "$LOGS/task_node.log" 2>&1 & pids+=($!)

tool_pose() {
  python - <<'PY'
import time, rclpy
from geometry_msgs.msg import PoseStamped
from hyperarm_description import contract
from hyperarm_description.qos import qos_for
rclpy.init()
node = rclpy.create_node("demo_probe", namespace=contract.DEFAULT_NAMESPACE)
got = []
node.create_subscription(PoseStamped, contract.TOOL_POSE, got.append, qos_for(contract.TOOL_POSE))
deadline = time.monotonic() + 10
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
if got:
    p = got[-1].pose.position
    x, y, z = (round(v, 4) + 0.0 for v in (p.x, p.y, p.z))  # + 0.0: no "-0.0000"
    print(f"   tool0 in {got[-1].header.frame_id}: x={x:.4f} y={y:.4f} z={z:.4f} m")
else:
    print("   no tool_pose received")
node.destroy_node()
rclpy.try_shutdown()
PY
}

echo "== task sequence: rest, ready (hyperarm_tasks/scripts/run_sequence.sh)"
"$(lib hyperarm_tasks run_sequence.sh)" rest
tool_pose
"$(lib hyperarm_tasks run_sequence.sh)" ready
tool_pose
echo "== demo done"
