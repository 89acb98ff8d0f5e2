#!/usr/bin/env bash
# `make demo`: Danko & Oh's pick-and-place (Section IV) on the mock, from a shell script.
#
# run_task.sh starts mock_driver (its default work cell and noise: the arm's repeatability
# is worse than the peg clearance, so the insertion needs the force-controlled dither),
# mock_camera (the camera's pictures, rendered by MuJoCo) and marker_detector (the objects'
# markers found in them: the task moves on what the camera sees), hybrid_force (the
# force-controlled insertion), task_node and task_recorder as separate processes (what
# `ros2 run` starts on the robot),
# and runs block_transfer (the block from the source peg onto the destination peg) then
# block_transfer_back (and back), printing every step. The run is recorded to an MCAP file
# and plotted to PNGs; the script says where. Real time: about 2 minutes.
# Output directory: HYPERARM_DEMO_OUT (default demo_output/ in the repository).
# Camera: HYPERARM_DEMO_CAMERA (default rendered; oracle: the mock's noisy true poses).
# Ctrl-C at any moment stops it within about 2 s (exit 130; nothing plotted): run_task.sh
# cancels the task and stops every node it started.
# DDS: this computer only. Unless you set ROS_AUTOMATIC_DISCOVERY_RANGE or
# FASTRTPS_DEFAULT_PROFILES_FILE yourself, over UDP loopback without Fast DDS' shared memory
# (hyperarm_bringup/config/fastdds_localhost.xml, as the tests run; its header says why: the
# shared-memory transport stalls stops for 1-3 s when many nodes stop at once). Nodes in
# other shells with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST still see these.
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
users_dds="${ROS_AUTOMATIC_DISCOVERY_RANGE:-}${FASTRTPS_DEFAULT_PROFILES_FILE:-}"
# shellcheck disable=SC1091
source scripts/env.sh
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
if [ -z "$users_dds" ]; then
  export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT
  export FASTRTPS_DEFAULT_PROFILES_FILE="$ROOT/ros2_ws/install/hyperarm_bringup/share/hyperarm_bringup/config/fastdds_localhost.xml"
else
  export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
fi
OUT="${HYPERARM_DEMO_OUT:-$ROOT/demo_output}"
CAMERA="${HYPERARM_DEMO_CAMERA:-rendered}"
case "$CAMERA" in oracle|rendered) ;; *) echo "demo: HYPERARM_DEMO_CAMERA is oracle or rendered, not '$CAMERA'" >&2; exit 2 ;; esac
mkdir -p "$OUT"
rm -f "$OUT/block_transfer.mcap"

echo "== hyperarm demo: block transfer there and back on the mock, camera $CAMERA (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
set +e
ros2_ws/src/hyperarm_tasks/scripts/run_task.sh --camera "$CAMERA" --record "$OUT/block_transfer.mcap" \
  --logs "$OUT/logs" block_transfer block_transfer_back
rc=$?
set -e
if [ "$rc" -eq 130 ]; then   # Ctrl-C: run_task.sh has stopped the task and every node
  echo "== demo interrupted (Ctrl-C): task cancelled, every node stopped; logs: $OUT/logs"
  exit 130
fi
if [ -f "$OUT/block_transfer.mcap" ]; then
  echo "== plotting the recording"
  ros2_ws/install/hyperarm_tasks/lib/hyperarm_tasks/plot_task "$OUT/block_transfer.mcap" --out "$OUT"
fi
echo "== demo $([ $rc -eq 0 ] && echo succeeded || echo "FAILED (exit $rc)")"
echo "   recording (MCAP, rosbag2/Foxglove): $OUT/block_transfer.mcap"
echo "   pictures: $OUT/tool_path.png $OUT/joints.png $OUT/insertion.png"
echo "   node logs: $OUT/logs"
exit $rc
