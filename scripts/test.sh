#!/usr/bin/env bash
# Run the whole test suite (all tiers) against the built workspace. Extra args go to pytest.
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
# Tests that start ROS processes isolate themselves (ROS_DOMAIN_ID per test, localhost only:
# Fast DDS over UDP loopback, without shared memory; TEST_DDS_ENV in ros2_ws/src/conftest.py
# sets the same for each test).
export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT
export FASTRTPS_DEFAULT_PROFILES_FILE="$ROOT/ros2_ws/src/hyperarm_bringup/config/fastdds_localhost.xml"
# that profile asks for 4 MB socket buffers (whole camera pictures over UDP); Linux grants
# at most net.core.rmem_max / wmem_max, silently
for buf in rmem_max wmem_max; do
  have=$(cat "/proc/sys/net/core/$buf" 2>/dev/null || echo 0)
  if [ "$have" -lt 4194304 ]; then
    echo "[test] warning: net.core.$buf is $have bytes (< 4 MB): pictures over UDP loopback" \
         "will be lost; as root: sysctl -w net.core.$buf=4194304" >&2
  fi
done
export PYTHONDONTWRITEBYTECODE=1
# Two pytest-xdist workers by default (HYPERARM_TEST_WORKERS=1 for one process): most tests
# wait on processes and DDS, so two run side by side on a 2-core machine; each worker has its
# own slice of ROS domains (ros2_ws/src/conftest.py). Whole files go to one worker.
workers="${HYPERARM_TEST_WORKERS:-2}"
parallel=()
if [ "$workers" -gt 1 ] && python -c "import xdist" 2>/dev/null; then
  parallel=(-n "$workers" --dist loadfile)
fi
start=$(date +%s)
set +e
python -m pytest "${parallel[@]}" --durations=25 "$@"
rc=$?
set -e
echo "[test] pytest exit code $rc after $(( $(date +%s) - start )) s"
if [ "$rc" -eq 5 ]; then
  echo "[test] pytest collected no tests: that is a failure, not a pass" >&2
  exit 1
fi
exit "$rc"
