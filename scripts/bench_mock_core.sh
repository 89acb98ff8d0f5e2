#!/usr/bin/env bash
# CPU time of the mock's simulation core (JointSim.step, one 5 ms step) in free motion, at
# rest and pressing the held block on a peg: this checkout's code against another commit's,
# alternated round by round (the machine's speed drifts: only runs next to each other
# compare). Each run is a fresh process taking the least of three passes per phase.
#
#   scripts/bench_mock_core.sh [BASE_COMMIT] [ROUNDS]      (default: 9b58b71, 3 rounds)
#
# BASE_COMMIT's hyperarm_driver and hyperarm_description come first on PYTHONPATH (a
# temporary git worktree), with BASE_COMMIT's own default workcell.yaml.
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
base="${1:-9b58b71}"
rounds="${2:-3}"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null
tmp="$(mktemp -d)"
cleanup() { git worktree remove --force "$tmp/base" >/dev/null 2>&1 || true; rm -rf "$tmp"; }
trap cleanup EXIT
git worktree add --detach "$tmp/base" "$base" >/dev/null 2>&1

cat > "$tmp/bench.py" <<'EOF'
import dataclasses, os, sys, time
from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.benchmarks.mock_benchmark import _scripted_press

cell = os.environ.get("BENCH_WORKCELL") or None
def once(steps=2000):
    cfg = load_mock_config(cell) if cell else load_mock_config()
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=0))
    sim = JointSim(load_description(), cfg)
    sim.command([f"joint{i}" for i in range(1, 10)], [0.5] * 9)
    out = {}
    for phase in ("free", "rest"):
        t = time.thread_time()
        for _ in range(steps):
            sim.step(0.005)
        out[phase] = (time.thread_time() - t) / steps * 1e6
    sim = JointSim(load_description(), cfg)
    _scripted_press(sim)
    t = time.thread_time()
    for _ in range(steps):
        sim.step(0.005)
    out["pressing"] = (time.thread_time() - t) / steps * 1e6
    if not sim.contact_force[2] > 0.1:
        sys.exit("the block left the peg's top while timed")
    return out
runs = [once() for _ in range(3)]
print("  ".join(f"{k} {min(r[k] for r in runs):4.0f} µs" for k in runs[0]))
EOF

echo "JointSim.step CPU per 5 ms step (least of 3 passes per run); base $base vs $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- ros2_ws || echo '+changes')"
for r in $(seq 1 "$rounds"); do
  printf 'round %d  base:  ' "$r"
  PYTHONPATH="$tmp/base/ros2_ws/src/hyperarm_driver:$tmp/base/ros2_ws/src/hyperarm_description:$PYTHONPATH" \
    BENCH_WORKCELL="$tmp/base/ros2_ws/src/hyperarm_driver/config/workcell.yaml" python "$tmp/bench.py"
  printf 'round %d  this:  ' "$r"
  python "$tmp/bench.py"
done
