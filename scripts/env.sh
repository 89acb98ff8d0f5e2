# Source this file (bash) to use the built workspace: `source scripts/env.sh`.
# Prefers /opt/ros/jazzy (the robot); falls back to the PyPI venv made by scripts/setup.sh.
_hyperarm_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_hyperarm_venv="${HYPERARM_VENV:-$_hyperarm_root/.venv}"
if [ -f /opt/ros/jazzy/setup.bash ]; then
  # shellcheck disable=SC1091
  source /opt/ros/jazzy/setup.bash
else
  export AMENT_PREFIX_PATH="$_hyperarm_venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$_hyperarm_venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
fi
export PATH="$_hyperarm_venv/bin:$PATH"
export VIRTUAL_ENV="$_hyperarm_venv"
if [ ! -f "$_hyperarm_root/ros2_ws/install/local_setup.bash" ]; then
  echo "hyperarm: the workspace is not built yet: run 'make setup' in $_hyperarm_root first," \
       "then 'source scripts/env.sh' again." >&2
  unset _hyperarm_root _hyperarm_venv
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "$_hyperarm_root/ros2_ws/install/local_setup.bash"
# the `hyperarm` command-line tool (hyperarm_bringup) on PATH
export PATH="$_hyperarm_root/ros2_ws/install/hyperarm_bringup/lib/hyperarm_bringup:$PATH"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# Fast DDS: participants re-announce every 0.5 s, so a one-shot `hyperarm` command finds the
# running drivers in about 0.1-0.5 s, not up to 3.6 s (hyperarm_bringup/config/fastdds.xml)
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_hyperarm_root/ros2_ws/install/hyperarm_bringup/share/hyperarm_bringup/config/fastdds.xml}"
unset _hyperarm_root _hyperarm_venv
