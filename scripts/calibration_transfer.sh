#!/usr/bin/env bash
# Issue 27's calibration check on the mock, as a user runs it (docs/perception.md):
#  1. a robot description whose camera is 2 cm and 5 deg off the mock's (the world's);
#  2. calibrate_camera from it on the mock's rendered pictures (mock_camera +
#     marker_detector), writing a calibrated description (--description-out);
#  3. the block transfer (run_task.sh --seed N) with no --description (the packaged camera,
#     the mock's own), with the perturbed one and with the calibrated one.
# Prints each run's result. Usage: scripts/calibration_transfer.sh [OUTDIR] [SEED]
# (default a temporary directory, seed 1). ROS_DOMAIN_ID is taken from the environment.
set -o pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh > /dev/null       # (colcon's setup scripts are not `set -u` clean)
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
D="${1:-$(mktemp -d /tmp/calibration-transfer.XXXXXX)}"
SEED="${2:-1}"
mkdir -p "$D"
python3 - "$D/perturbed.yaml" <<'PY'
import math
import sys

from hyperarm_description.model import load_description, write_description_copy

desc = load_description(None, "arm")
d = 0.02 / math.sqrt(3.0)


def edit(data: dict) -> None:
    data["camera"]["xyz"] = [v + d for v in desc.camera.xyz]
    data["camera"]["rpy"] = [desc.camera.rpy[0] + math.radians(5.0), *desc.camera.rpy[1:]]


write_description_copy(None, sys.argv[1], edit, "# the camera 2 cm and 5 deg off\n")
PY
L=ros2_ws/install
pids=()
"$L/hyperarm_driver/lib/hyperarm_driver/mock_driver" --ros-args -p detections:=none \
    > "$D/mock.log" 2>&1 & pids+=($!)
"$L/hyperarm_perception/lib/hyperarm_perception/mock_camera" --ros-args \
    -p "calibration_target:=0 0.02 0.026 0 0 0" > "$D/mock_camera.log" 2>&1 & pids+=($!)
"$L/hyperarm_perception/lib/hyperarm_perception/marker_detector" > "$D/marker_detector.log" 2>&1 & pids+=($!)
"$L/hyperarm_control/lib/hyperarm_control/arm_controller" > "$D/arm_controller.log" 2>&1 & pids+=($!)
"$L/hyperarm_perception/lib/hyperarm_perception/calibrate_camera" \
    --description "$D/perturbed.yaml" -o "$D/extrinsics.yaml" \
    --description-out "$D/calibrated.yaml" > "$D/calibrate.log" 2>&1
rc=$?
kill -INT "${pids[@]}"; wait "${pids[@]}"
echo "calibrate_camera: exit $rc"; tail -3 "$D/calibrate.log"
[ "$rc" -eq 0 ] || exit 1
python3 - "$D/calibrated.yaml" <<'PY'
import math
import sys

import numpy as np

from hyperarm_description.mjcf import camera_link_pose
from hyperarm_description.model import load_description
from hyperarm_perception.markers import rotation_angle

t = camera_link_pose(load_description(None, "arm"))
c = camera_link_pose(load_description(sys.argv[1], "arm"))
print(f"calibrated camera vs the mock's: {np.linalg.norm(c[:3, 3] - t[:3, 3]) * 1e3:.2f} mm, "
      f"{math.degrees(rotation_angle(c[:3, :3].T @ t[:3, :3])):.3f} deg")
PY
for which in packaged perturbed calibrated; do
  opt=()
  [ "$which" = packaged ] || opt=(--description "$D/$which.yaml")
  "$L/hyperarm_tasks/lib/hyperarm_tasks/run_task.sh" --seed "$SEED" "${opt[@]}" block_transfer \
      > "$D/transfer-$which.log" 2>&1
  echo "block_transfer, $which description: exit $?"
  grep "^run_task: \(succeeded\|failed\)\|^run_task: time per step" "$D/transfer-$which.log"
done
echo "logs in $D"
