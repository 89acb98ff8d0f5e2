#!/usr/bin/env bash
# run_task.sh: start the hyperarm stack, run one task from the shell, stop everything.
#
#   run_task.sh [options] TASK [TASK...]     e.g. run_task.sh block_transfer
#
# Several tasks run one after the other on the same stack (e.g. block_transfer
# block_transfer_back: there and back), stopping at the first failure.
# Starts the drivers (the mock by default), the force node and the task node as separate
# processes, waits until they are ready (joint_states, the run_task action and the force
# node's enable service: no fixed sleeps), sends the
# goal, prints a line per step and the result, and exits 0 on success, 1 on failure (with
# the reason), 2 on bad use, 130 after Ctrl-C or SIGTERM. Every process it started is stopped
# with SIGTERM (one at a time, the last started first; SIGKILL only for one still running 10 s later, which is reported
# and is a bug) on success, failure, Ctrl-C or SIGTERM. A Ctrl-C at any moment works: during
# the stack's start-up nothing is sent; once the task runs it is cancelled first (the arm
# holds, before the next step starts); the script exits within about 2 s.
# Installed as lib/hyperarm_tasks/run_task.sh; also runnable from the repository.
#
# Options:
#   --variant V          arm (default) or rail_arm
#   --hardware PARAMS    real drivers (dynamixel_driver; pmac_rail_driver on rail_arm) with
#                        this ROS parameters file instead of the mock
#   --workcell FILE      the work-cell YAML: the mock's cell (default: its packaged one), and
#                        the table/pegs/poles the task node checks its paths against
#   --seed N             the mock's imperfection and camera seeds (a copy of the work cell)
#   --description FILE   the robot description of the nodes that command the robot
#                        (task_node, hybrid_force, the hardware drivers): their
#                        description_file. The mock keeps its packaged one: it is the
#                        world, FILE what you believe of it (e.g. calibrate_camera's
#                        --description-out, to compare a transfer with and without it)
#   --camera C           the mock's camera: oracle (default: the true poses plus noise on
#                        detections) or rendered (the mock's pictures rendered by MuJoCo,
#                        mock_camera, and marker_detector finding the markers in them)
#   --no-force-node      do not start hybrid_force: force_insert then presses with its
#                        position pseudo-goal fallback instead of hybrid force control
#   --record FILE        record the run to FILE (MCAP: joint_states, joint_command,
#                        hybrid_goal, ee_wrench, detections, task feedback)
#   --tasks-dir DIR      user task files (searched before the packaged ones)
#   --timeout S          task timeout (default 300)
#   --logs DIR           keep the nodes' logs there (default: a temporary directory)
#   -h, --help           this text
set -uo pipefail

usage() { sed -n '2,/^set -uo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; }

variant=arm hardware="" workcell="" seed="" record="" tasks_dir="" timeout=300 logs="" tasks=()
description=""
camera=oracle
force_node=1
while [ $# -gt 0 ]; do
  case "$1" in
    -h|--help) usage; exit 0 ;;
    --variant) variant="${2:?--variant needs a value}"; shift 2 ;;
    --hardware) hardware="${2:?--hardware needs a parameters file}"; shift 2 ;;
    --workcell) workcell="${2:?--workcell needs a file}"; shift 2 ;;
    --seed) seed="${2:?--seed needs a number}"; shift 2 ;;
    --description) description="${2:?--description needs a file}"; shift 2 ;;
    --record) record="${2:?--record needs a file}"; shift 2 ;;
    --camera) camera="${2:?--camera needs oracle or rendered}"; shift 2 ;;
    --force-node) force_node=1; shift ;;     # the default (kept for old scripts)
    --no-force-node) force_node=0; shift ;;
    --tasks-dir) tasks_dir="${2:?--tasks-dir needs a directory}"; shift 2 ;;
    --timeout) timeout="${2:?--timeout needs seconds}"; shift 2 ;;
    --logs) logs="${2:?--logs needs a directory}"; shift 2 ;;
    -*) echo "run_task.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) tasks+=("$1"); shift ;;
  esac
done
[ "${#tasks[@]}" -gt 0 ] || { echo "run_task.sh: which task? (see --help)" >&2; exit 2; }
case "$variant" in arm|rail_arm) ;; *) echo "run_task.sh: --variant arm or rail_arm" >&2; exit 2 ;; esac
[ -z "$hardware" ] || [ -f "$hardware" ] || { echo "run_task.sh: $hardware: no such file" >&2; exit 2; }
[ -z "$seed" ] || [[ "$seed" =~ ^[0-9]+$ ]] || { echo "run_task.sh: --seed must be an integer" >&2; exit 2; }
case "$camera" in oracle|rendered) ;; *) echo "run_task.sh: --camera oracle or rendered" >&2; exit 2 ;; esac
[ -z "$hardware" ] || [ "$camera" = oracle ] || { echo "run_task.sh: --camera rendered is the mock's (not with --hardware)" >&2; exit 2; }
if [ -n "$description" ]; then
  [ -f "$description" ] || { echo "run_task.sh: --description: no file $description" >&2; exit 2; }
  description="$(realpath "$description")"
fi

# The workspace: sourced already (installed use), else this repository's.
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if ! python3 -c "import hyperarm_tasks" >/dev/null 2>&1; then
  root="$(cd "$here/../../../.." 2>/dev/null && pwd)"
  if [ -f "$root/scripts/env.sh" ]; then
    set +u
    # shellcheck disable=SC1091
    source "$root/scripts/env.sh"
    set -u
  else
    echo "run_task.sh: hyperarm is not on the path: source the workspace (scripts/env.sh)" >&2
    exit 2
  fi
fi
# The install prefixes of the packages it runs, looked up once (one Python start, not one
# per executable: each took 0.1-0.3 s of the start-up).
prefixes="$(python3 -c "
from ament_index_python.packages import get_package_prefix as g
for p in ('hyperarm_driver', 'hyperarm_control', 'hyperarm_tasks', 'hyperarm_perception'):
    try:
        print(p, g(p))
    except (LookupError, ValueError):
        pass" 2>/dev/null)"
exe() {  # path of an installed executable, as `ros2 run` finds it
  local prefix
  prefix="$(awk -v p="$1" '$1 == p { print $2 }' <<< "$prefixes")"
  [ -n "$prefix" ] || { echo "run_task.sh: package $1 not found (make setup)" >&2; exit 2; }
  echo "$prefix/lib/$1/$2"
}

if [ -n "$logs" ]; then mkdir -p "$logs"; else logs="$(mktemp -d -t hyperarm-run.XXXXXX)"; fi
: > "$logs/pids"   # "name pid" of every process started (tests check they are gone)
pids=() names=()
stopping=0
# Ctrl-C / SIGTERM from here on: remembered (and passed to the client, once there is one);
# nothing more is started, the stack is stopped and the exit code is 130.
client=""
interrupted=0
# The client gets SIGTERM for either: it starts (a background job) with SIGINT ignored until
# its handler is set, while SIGTERM ends it at once before that (nothing sent yet).
signalled_at=""
forward() {
  interrupted=1
  [ -n "$signalled_at" ] || signalled_at=${EPOCHREALTIME//[!0-9]/}
  [ -z "$client" ] || kill -TERM "$client" 2>/dev/null
}
trap 'forward INT' INT
trap 'forward TERM' TERM
stop_if_interrupted() { [ "$interrupted" = 0 ] || exit 130; }
cleanup() {
  [ "$stopping" = 1 ] && return
  stopping=1
  trap '' INT TERM          # a second Ctrl-C while stopping changes nothing
  local i pid before took
  # SIGTERM: a node stops on it as on SIGINT (its shutdown policy runs), and one still in
  # Python's start-up (before any handler; nothing opened yet) ends at once, quietly.
  # One at a time, the last started first (commanders before the drivers): Fast DDS 2.14
  # can spin for seconds, or for good, deleting a participant while it handles a peer's
  # removal (eProsima/Fast-DDS#6513; seen here: 3 s, and a hang until SIGKILL), which
  # nodes stopped all at once provoke. A node takes ~0.03 s to stop.
  for (( i = ${#pids[@]} - 1; i >= 0; i-- )); do
    pid="${pids[$i]}"
    before=${EPOCHREALTIME//[!0-9]/}
    kill -TERM "$pid" 2>/dev/null
    if ! timeout 10 tail -s 0.01 --pid="$pid" -f /dev/null 2>/dev/null; then
      echo "run_task.sh: ${names[$i]} (pid $pid) did not stop on SIGTERM; killing it" >&2
      kill -KILL "$pid" 2>/dev/null
    fi
    wait "$pid" 2>/dev/null
    # a slow stop is said, with the node's own account of it (run_node prints its phases)
    took=$(( (${EPOCHREALTIME//[!0-9]/} - before) / 1000 ))
    if [ "$took" -gt 500 ]; then
      echo "run_task.sh: ${names[$i]} stopped ${took} ms after SIGTERM" >&2
      grep -h "shutdown took" "$logs/${names[$i]}.log" >&2 2>/dev/null
    fi
  done
}
trap cleanup EXIT

start() {  # start NAME EXECUTABLE ARGS...: its own session, so a terminal Ctrl-C reaches
  local name="$1"; shift       # only this script and run_task, which cancels first
  stop_if_interrupted
  # `trap - INT` in the job's subshell: SIGINT at its default again (a background job
  # ignores it), so a node answers anyone's SIGINT as documented, from its first moment
  # (setsid execs in place: the pid is the node's).
  ( trap - INT; exec setsid "$@" >"$logs/$name.log" 2>&1 < /dev/null ) &
  pids+=($!); names+=("$name")
  echo "$name $!" >> "$logs/pids"
}

ros=(-p "variant:=$variant")
mock=("${ros[@]}")          # the mock: the world, with its packaged description
[ -z "$description" ] || ros+=(-p "description_file:=$description")
if [ -n "$hardware" ]; then
  start dynamixel_driver "$(exe hyperarm_driver dynamixel_driver)" --ros-args --params-file "$hardware" "${ros[@]}"
  if [ "$variant" = rail_arm ]; then
    start pmac_rail_driver "$(exe hyperarm_driver pmac_rail_driver)" --ros-args --params-file "$hardware" "${ros[@]}"
  fi
else
  # the mock's work cell: the task node checks its paths against the same table and pegs
  workcell="${workcell:-$(dirname "$(dirname "$(dirname "$(exe hyperarm_driver mock_driver)")")")/share/hyperarm_driver/config/workcell.yaml}"
  if [ -n "$seed" ]; then
    src="$workcell"
    workcell="$logs/workcell-seed$seed.yaml"
    python3 - "$src" "$workcell" "$seed" <<'PY'
import sys, yaml
src, dst, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
cell = yaml.safe_load(open(src))
cell.setdefault("imperfections", {})["seed"] = seed
cell.setdefault("camera", {})["seed"] = seed + 1000
yaml.safe_dump(cell, open(dst, "w"), sort_keys=False)
PY
  [ -f "$workcell" ] || { stop_if_interrupted; exit 2; }
  fi
  [ -z "$workcell" ] || mock+=(-p "workcell_file:=$workcell")
  [ "$camera" = oracle ] || mock+=(-p "detections:=none")
  start mock_driver "$(exe hyperarm_driver mock_driver)" --ros-args "${mock[@]}"
  if [ "$camera" = rendered ]; then
    cam=(-p "variant:=$variant" -p "workcell_file:=$workcell")
    [ -z "$seed" ] || cam+=(-p "seed:=$seed")
    start mock_camera "$(exe hyperarm_perception mock_camera)" --ros-args "${cam[@]}"
    start marker_detector "$(exe hyperarm_perception marker_detector)" --ros-args "${ros[@]}"
  fi
fi
if [ "$force_node" = 1 ]; then
  start hybrid_force "$(exe hyperarm_control hybrid_force)" --ros-args "${ros[@]}"
fi
task_args=("${ros[@]}")
[ -z "$workcell" ] || task_args+=(-p "world_file:=$workcell" -p "collision_check:=true")
[ -z "$tasks_dir" ] || task_args+=(-p "tasks_dir:=$tasks_dir")
start task_node "$(exe hyperarm_tasks task_node)" --ros-args "${task_args[@]}"
if [ -n "$record" ]; then
  start task_recorder "$(exe hyperarm_tasks task_recorder)" --ros-args -p "output:=$record"
fi

where="the mock"
[ -z "$hardware" ] || where="the hardware (drivers with $hardware)"
echo "run_task.sh: ${tasks[*]} on $where ($variant), logs in $logs"
# run_task in the background so that SIGTERM/SIGINT to this script are handled at once:
# they are forwarded to run_task, which cancels the task before everything is stopped
# (and sends none if it has not sent it yet).
rc=0
n=0
for task in "${tasks[@]}"; do
  n=$((n + 1))
  [ "${#tasks[@]}" -eq 1 ] || echo "== task $n/${#tasks[@]}: $task"
  waits=()
  [ "$force_node" = 0 ] || waits=(--wait-force)
  [ "$camera" = oracle ] || waits+=(--wait-detections)
  runner="$(exe hyperarm_tasks run_task)"
  stop_if_interrupted
  "$runner" "$task" --timeout "$timeout" --wait-ready 60 "${waits[@]}" &
  client=$!
  # a signal between the start and `client=$!` was not forwarded: forward it now
  [ "$interrupted" = 0 ] || kill -TERM "$client" 2>/dev/null
  while :; do
    wait "$client"; rc=$?
    kill -0 "$client" 2>/dev/null || break   # wait returns early when a trap ran
  done
  client=""
  if [ -n "$signalled_at" ]; then   # a slow stop is said (where the time went)
    took=$(( (${EPOCHREALTIME//[!0-9]/} - signalled_at) / 1000 ))
    [ "$took" -le 1000 ] || echo "run_task.sh: run_task stopped ${took} ms after the signal" >&2
  fi
  [ "$rc" -eq 0 ] && [ "$interrupted" = 0 ] || break
done
[ "$interrupted" = 0 ] || rc=130
for i in "${!pids[@]}"; do
  if ! kill -0 "${pids[$i]}" 2>/dev/null; then
    echo "run_task.sh: ${names[$i]} exited early; its log ($logs/${names[$i]}.log) ends:" >&2
    tail -5 "$logs/${names[$i]}.log" >&2
  fi
done
if [ -n "$record" ]; then
  cleanup   # finish the recording before saying where it is
  [ -f "$record" ] && echo "run_task.sh: recording in $record"
fi
exit "$rc"
