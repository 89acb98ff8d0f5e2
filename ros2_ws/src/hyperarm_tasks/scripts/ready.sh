#!/usr/bin/env bash
# ready.sh: move the arm to the ready pose (gripper open, q = 0) through the task node
# (the `ready` task, sent by run_task to a running stack).
#
#   ready.sh [--namespace /hyperarm] [--timeout 60] [--quiet]
#
# The stack (a driver and task_node) must be running; run_task.sh ready starts one.
# Exit code 0 when the arm is at the ready pose, 1 on failure, 2 on bad use.
#   -h, --help    this text
set -euo pipefail
case "${1:-}" in
  -h|--help) sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
esac
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"  # the install lib dir, next to run_task
runner="$here/run_task"
[ -x "$runner" ] || runner="$(command -v run_task || true)"
[ -n "$runner" ] || { echo "ready.sh: run_task not found (source the workspace)" >&2; exit 2; }
exec "$runner" ready "$@"
