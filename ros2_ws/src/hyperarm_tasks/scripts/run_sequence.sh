#!/usr/bin/env bash
# Run several tasks in order, stopping at the first failure.
# Usage: run_sequence.sh TASK [TASK ...]      e.g. run_sequence.sh ready rest ready
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"  # the install lib dir, next to run_task
runner="$here/run_task"
[ -x "$runner" ] || runner="$(command -v run_task || true)"
[ -n "$runner" ] || { echo "run_sequence.sh: run_task not found (source the workspace)" >&2; exit 2; }
[ $# -gt 0 ] || { echo "usage: run_sequence.sh TASK [TASK ...]" >&2; exit 2; }
for task in "$@"; do
  echo "== $task"
  "$runner" "$task" || { echo "run_sequence.sh: task '$task' failed" >&2; exit 1; }
done
