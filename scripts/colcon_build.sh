#!/usr/bin/env bash
# colcon build of a workspace by the hyperarm venv's interpreter (used by scripts/setup.sh).
#
# colcon writes each installed Python executable's shebang from the interpreter colcon itself
# runs under (sys.executable). apt's /usr/bin/colcon runs under /usr/bin/python3, which cannot
# import what requirements-robot.txt put into the venv (viser, mcap): `viewer`,
# `task_recorder`, `plot_task` then fail with ModuleNotFoundError. So colcon is run by the
# venv's python: on the PyPI route the venv holds colcon; on the robot the venv
# (--system-site-packages) imports apt's colcon. scripts/robot_route/check_executables.py
# checks the result.
#
# usage: colcon_build.sh VENV WORKSPACE [colcon build options ...]
set -euo pipefail
VENV="$1"
WS="$2"
shift 2
cd "$WS"
# the same entry point as the `colcon` script, under the venv's interpreter
exec "$VENV/bin/python" -c \
  'import sys; from colcon_core.command import main; sys.argv[0] = "colcon"; sys.exit(main())' \
  --log-base log build --symlink-install --event-handlers console_cohesion- status- "$@" \
  --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VENV/bin/python"
