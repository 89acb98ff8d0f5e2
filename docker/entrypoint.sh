#!/usr/bin/env bash
# Source ROS 2 Jazzy and the hyperarm workspace, then run the given command.
set -e
# shellcheck disable=SC1091
source /opt/hyperarm/scripts/env.sh
exec "$@"
