#!/usr/bin/env bash
# The ROS-free core tests (pytest -m core) under Ubuntu 24.04's numpy 1.26, as far as PyPI
# allows: a venv of this machine's Python holding the apt versions of
# scripts/robot_route/ubuntu-24.04-apt.txt (numpy 1.26.4, PyYAML 6.0.1, pytest 7.4.4,
# hypothesis 6.98.15, ...), the Dynamixel SDK (the same ROBOTIS code as
# ros-jazzy-dynamixel-sdk's Python module) and requirements-robot.txt. Test modules that
# need pinocchio (every PyPI `pin` wheel requires numpy>=2) or rclpy are reported as
# skipped, naming the module. Extra arguments go to pytest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="${HYPERARM_NP126_VENV:-$ROOT/.stamps/np126-venv}"
PY="${PYTHON:-python3}"
HERE="$ROOT/scripts/robot_route"
want="$(cat "$HERE/ubuntu-24.04-apt.txt" "$ROOT/requirements-robot.txt" | sha256sum | cut -d' ' -f1)"
if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$VENV/.stamp" 2>/dev/null)" != "$want" ]; then
  echo "[np126] creating $VENV (numpy 1.26.4 and the other apt versions)"
  "$PY" -m venv "$VENV"
  "$VENV/bin/pip" install -q -c "$HERE/ubuntu-24.04-apt.txt" -r "$HERE/ubuntu-24.04-apt.txt" \
      dynamixel-sdk==4.1.0 -r "$ROOT/requirements-robot.txt" 2>&1 \
    | { grep -v "is ignored: it is neither a file nor a directory" || true; }
  echo "$want" > "$VENV/.stamp"
fi
"$VENV/bin/python" -c 'import numpy; assert numpy.__version__ == "1.26.4", numpy.__version__; print("[np126] numpy", numpy.__version__)'
pkgs=""
for d in "$ROOT"/ros2_ws/src/hyperarm_*/; do [ -f "$d/setup.py" ] && pkgs="$pkgs:$d"; done
cd "$ROOT"
PYTHONPATH="$HERE${pkgs}" PYTHONDONTWRITEBYTECODE=1 \
  "$VENV/bin/python" -m pytest -p np126_plugin -m core -q "$@"
