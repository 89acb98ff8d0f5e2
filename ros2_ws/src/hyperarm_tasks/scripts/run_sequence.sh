#!/usr/bin/env bash
# run_sequence.sh: run several tasks in order on a running stack, stopping at the first
# failure (each one sent by run_task).
#
#   run_sequence.sh TASK [TASK ...]      e.g. run_sequence.sh ready rest ready
#
# The stack (a driver and task_node) must be running; run_task.sh TASK TASK... starts one
# and runs the tasks the same way. Exit code 0 when every task succeeded, 1 at the first
# failure (or a Ctrl-C: the running task is cancelled, the rest not started), 2 on bad use.
#   -h, --help    this text
set -euo pipefail
usage() { sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; }
case "${1:-}" in
  -h|--help) usage; exit 0 ;;
  -*) echo "run_sequence.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
esac
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"  # the install lib dir, next to run_task
runner="$here/run_task"
[ -x "$runner" ] || runner="$(command -v run_task || true)"
[ -n "$runner" ] || { echo "run_sequence.sh: run_task not found (source the workspace)" >&2; exit 2; }
[ $# -gt 0 ] || { echo "usage: run_sequence.sh TASK [TASK ...] (see --help)" >&2; exit 2; }
for task in "$@"; do
  echo "== $task"
  "$runner" "$task" || { echo "run_sequence.sh: task '$task' failed" >&2; exit 1; }
done
