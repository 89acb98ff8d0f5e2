#!/usr/bin/env bash
# Move the arm to the ready pose (gripper open, q = 0) through the task node.
# Usage: ready.sh [--namespace /hyperarm] [--timeout 60]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"  # the install lib dir, next to run_task
runner="$here/run_task"
[ -x "$runner" ] || runner="$(command -v run_task || true)"
[ -n "$runner" ] || { echo "ready.sh: run_task not found (source the workspace)" >&2; exit 2; }
exec "$runner" ready "$@"
