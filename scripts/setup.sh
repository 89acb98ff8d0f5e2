#!/usr/bin/env bash
# Idempotent set-up of the hyperarm workspace, used by `make demo`, `make test` and CI.
#
# 1. ROS 2 Jazzy: /opt/ros/jazzy when it exists (the robot), else a .venv with the ROS 2
#    Jazzy PyPI wheels pinned in requirements.lock (development machines, CI).
# 2. colcon build of ros2_ws/ (symlink install).
#
# Each step is skipped when its inputs did not change (stamp files hold their hashes), so a
# second run takes a second or two. FORCE=1 redoes everything.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${HYPERARM_VENV:-$ROOT/.venv}"
WS="$ROOT/ros2_ws"
STAMPS="$ROOT/.stamps"
mkdir -p "$STAMPS"

log() { printf '[setup] %s\n' "$*"; }
hash_of() { sha256sum "$@" | sha256sum | cut -d' ' -f1; }
stamp_ok() { [ "${FORCE:-0}" != 1 ] && [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }

pick_python() {
  for p in "${PYTHON:-}" python3.11 python3.12 python3; do
    [ -n "$p" ] && command -v "$p" >/dev/null 2>&1 && { echo "$p"; return; }
  done
  echo "no python3 found" >&2; exit 1
}

if [ -f /opt/ros/jazzy/setup.bash ]; then
  # The robot: ROS, pinocchio, the Dynamixel SDK, numpy, PyYAML, pytest, hypothesis from apt
  # (rosdep keys in each package.xml). The venv (--system-site-packages) only adds what apt
  # lacks (requirements-robot.txt), with the system numpy pinned: PyPI's `pin` needs numpy 2,
  # and ROS Jazzy's apt extensions do not load under numpy 2. See docs/robot-install.md.
  log "using /opt/ros/jazzy"
  set +u; source /opt/ros/jazzy/setup.bash; set -u
  if command -v rosdep >/dev/null 2>&1; then
    if ! rosdep check --from-paths "$WS/src" --ignore-src -q >/dev/null 2>&1; then
      if [ "$(id -u)" = 0 ] || [ "${HYPERARM_ROSDEP_INSTALL:-0}" = 1 ]; then
        log "rosdep install (apt packages named in the package.xml files)"
        rosdep install --from-paths "$WS/src" --ignore-src -y -r
      else
        echo "[setup] apt dependencies are missing; install them with" >&2
        echo "  rosdep install --from-paths ros2_ws/src --ignore-src -y" >&2
        echo "(once: sudo rosdep init; rosdep update). Missing:" >&2
        rosdep check --from-paths "$WS/src" --ignore-src >&2 || true
        exit 1
      fi
    fi
  else
    log "rosdep not found (apt install python3-rosdep): not checking apt dependencies"
  fi
  if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv --system-site-packages "$VENV"
  fi
  want="$(hash_of "$ROOT/requirements-robot.txt")-apt"
  if ! stamp_ok python "$want"; then
    # Never replace apt's numpy: pin the version the system has.
    np="$("$VENV/bin/python" -c 'import numpy; print(numpy.__version__)')"
    echo "numpy==$np" > "$STAMPS/robot-constraints.txt"
    "$VENV/bin/pip" install -q -c "$STAMPS/robot-constraints.txt" \
        -r "$ROOT/requirements-robot.txt" 2>&1 \
      | { grep -v "is ignored: it is neither a file nor a directory" || true; }
    "$VENV/bin/python" - "$np" <<'PY'
import sys, numpy, pinocchio
assert numpy.__version__ == sys.argv[1], f"numpy changed: {numpy.__version__}"
assert pinocchio.__file__.startswith("/opt/ros/"), f"a second pinocchio: {pinocchio.__file__}"
PY
    echo "$want" > "$STAMPS/python"
  fi
  PREFIX=""
else
  PY="$(pick_python)"
  # The ROS 2 Jazzy wheels on PyPI are built for CPython 3.11 only.
  if [ "$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" != "3.11" ]; then
    echo "[setup] without /opt/ros/jazzy, hyperarm needs Python 3.11 (the ROS 2 Jazzy PyPI" \
         "wheels are cp311); found $("$PY" --version 2>&1). Install python3.11 or set PYTHON=." >&2
    exit 1
  fi
  if [ ! -x "$VENV/bin/python" ]; then
    log "creating $VENV with $PY"
    "$PY" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 \
      | { grep -v "is ignored: it is neither a file nor a directory" || true; }
  fi
  want="$(hash_of "$ROOT/requirements.lock")"
  if ! stamp_ok python "$want"; then
    log "installing pinned ROS 2 Jazzy wheels and Python packages (requirements.lock)"
    "$VENV/bin/pip" install -q -r "$ROOT/requirements.lock" 2>&1 \
      | { grep -v "is ignored: it is neither a file nor a directory" || true; }
    # The wheels' CMake configs hard-code the wheel builder's Python paths; point them at ours.
    "$VENV/bin/python" "$ROOT/scripts/fix_cmake_paths.py" "$VENV"
    echo "$want" > "$STAMPS/python"
  fi
  PREFIX="$VENV"
  # The browser viewer's test loads the page in headless Chromium (Debian packages).
  # Installed only when missing; the package lists are refreshed only if apt cannot find
  # the packages. HYPERARM_NO_BROWSER=1 skips this (the browser test then skips).
  if [ "${HYPERARM_NO_BROWSER:-0}" != 1 ] && command -v apt-get >/dev/null 2>&1 \
      && ! { command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; }; then
    if [ "$(id -u)" = 0 ]; then
      log "installing chromium and chromium-driver (apt) for the viewer's browser test"
      export DEBIAN_FRONTEND=noninteractive
      if ! apt-get install -y -q --no-install-recommends chromium chromium-driver \
            > "$STAMPS/apt-chromium.log" 2>&1; then
        apt-get update -q > /dev/null
        apt-get install -y -q --no-install-recommends chromium chromium-driver \
          > "$STAMPS/apt-chromium.log" 2>&1 || { cat "$STAMPS/apt-chromium.log"; exit 1; }
      fi
    else
      log "chromium/chromedriver missing (sudo apt-get install chromium chromium-driver):" \
          "the viewer's browser test will skip"
    fi
  fi
  # MuJoCo's offscreen pictures (generate_mjcf --render with MUJOCO_GL=egl, docs/mujoco.md)
  # need EGL and Mesa's software renderer (Debian packages): installed only when missing,
  # as chromium above.
  if command -v apt-get >/dev/null 2>&1 && command -v dpkg-query >/dev/null 2>&1; then
    egl_missing=""
    for pkg in libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri; do
      dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "ok installed" \
        || egl_missing="$egl_missing $pkg"
    done
    if [ -n "$egl_missing" ]; then
      if [ "$(id -u)" = 0 ]; then
        log "installing$egl_missing (apt) for MuJoCo's offscreen rendering"
        export DEBIAN_FRONTEND=noninteractive
        # shellcheck disable=SC2086
        if ! apt-get install -y -q --no-install-recommends $egl_missing \
              > "$STAMPS/apt-egl.log" 2>&1; then
          apt-get update -q > /dev/null
          # shellcheck disable=SC2086
          apt-get install -y -q --no-install-recommends $egl_missing \
            > "$STAMPS/apt-egl.log" 2>&1 || { cat "$STAMPS/apt-egl.log"; exit 1; }
        fi
      else
        log "missing$egl_missing (sudo apt-get install$egl_missing): MuJoCo's offscreen" \
            "rendering (MUJOCO_GL=egl) will not work"
      fi
    fi
  fi
  export CMAKE_PREFIX_PATH="$VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
fi

export PATH="$VENV/bin:$PATH"

# Rebuild only when something colcon installs changed: package manifests, setup files,
# interface definitions, data files, scripts, and the list of non-Python files. Python
# packages are installed in develop mode (--symlink-install), so editing or adding a module
# needs no rebuild; a new top-level Python package or console script does.
build_inputs() {
  (cd "$WS/compat" && find . -type f | LC_ALL=C sort | xargs sha256sum)
  echo "skip: ${COMPAT_SKIP[*]:-}"
  (cd "$WS/src" && find . -type f ! -name '*.py' ! -name '*.pyc' \
     ! -path '*/__pycache__/*' ! -path '*/.pytest_cache/*' | LC_ALL=C sort)
  (cd "$WS/src" && find . -mindepth 3 -maxdepth 3 -name __init__.py | LC_ALL=C sort)
  (cd "$WS/src" && find . -type f \( -name package.xml -o -name setup.py -o -name setup.cfg \
     -o -name CMakeLists.txt -o -name '*.msg' -o -name '*.srv' -o -name '*.action' \
     -o -name '*.yaml' -o -name '*.urdf' -o -name '*.sh' \) ! -path '*/__pycache__/*' \
     | LC_ALL=C sort | xargs sha256sum)
  (cd "$ROOT" && sha256sum scripts/colcon_build.sh)   # how it builds (the scripts' interpreter)
}
# ros2_ws/compat holds minimal control_msgs and tf2_msgs for the PyPI route, whose wheels lack
# them (ros2_ws/compat/README.md). Where /opt/ros/jazzy provides one (the robot, through
# rosdep), it is skipped, so that it never shadows apt's package.
COMPAT_SKIP=()
for pkg in control_msgs tf2_msgs; do
  if [ -f "/opt/ros/jazzy/share/$pkg/package.xml" ]; then COMPAT_SKIP+=("$pkg"); fi
done
want="$(build_inputs | sha256sum | cut -d' ' -f1)"
if ! stamp_ok build "$want" || [ ! -f "$WS/install/local_setup.bash" ]; then
  log "colcon build (ros2_ws)"
  cd "$WS"
  # colcon cannot switch an existing build/ between symlink and copy installs; a failed
  # earlier build can leave it half-made. Start clean when the stamp is missing.
  if [ ! -f "$STAMPS/build" ]; then rm -rf build install log; fi
  # colcon runs under the venv's python, so every installed script's shebang is the venv's
  # (apt's colcon would write /usr/bin/python3, which cannot import requirements-robot.txt)
  skip_args=()
  if [ "${#COMPAT_SKIP[@]}" -gt 0 ]; then
    log "using apt's ${COMPAT_SKIP[*]} (not building ros2_ws/compat's)"
    skip_args=(--packages-skip "${COMPAT_SKIP[@]}")
  fi
  if ! bash "$ROOT/scripts/colcon_build.sh" "$VENV" "$WS" "${skip_args[@]}" \
      > "$STAMPS/colcon.log" 2>&1; then
    cat "$STAMPS/colcon.log"
    rm -f "$STAMPS/build"
    echo "[setup] colcon build failed (log above)" >&2
    exit 1
  fi
  echo "$want" > "$STAMPS/build"
  log "built: $(ls "$WS/install" | grep -c hyperarm_) packages" \
      "(+ $(ls "$WS/install" | grep -cE '^(control_msgs|tf2_msgs)$') from ros2_ws/compat)"
fi
log "ready (source scripts/env.sh to use the workspace)"
