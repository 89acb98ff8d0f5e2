# hyperarm: the two commands are `make demo` and `make test`; both set everything up first.
SHELL := /bin/bash
.DEFAULT_GOAL := help

.PHONY: help setup build demo test test-core check-robot-route lock clean

help:
	@echo "make demo   - set up (idempotent) and run the demo on the mock driver"
	@echo "make test   - set up (idempotent) and run the whole test suite"
	@echo "make setup  - only the set-up (venv or /opt/ros/jazzy, colcon build)"
	@echo "make test-core - only the ROS-free core tests"
	@echo "make check-robot-route - robot pip plan vs apt numpy 1.26, installed scripts' interpreter, core tests under it"
	@echo "make clean  - remove build products (keeps .venv)"

setup:
	@bash scripts/setup.sh

build: setup

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh $(ARGS)

# Only the ROS-free core tier (no rclpy), quick.
test-core: setup
	@bash scripts/test.sh -m core $(ARGS)

# The robot route's pip plan against Ubuntu 24.04's numpy 1.26, every installed executable's
# interpreter (the venv's) and imports, and the core tests under numpy 1.26
# (docs/robot-install.md). Sets up first: it also runs on a fresh clone.
check-robot-route: setup
	@python3 scripts/robot_route/check_plan.py --venv .stamps/apt-venv
	@bash -c 'source scripts/env.sh > /dev/null && python scripts/robot_route/check_executables.py'
	@bash scripts/robot_route/core_tests.sh

# Regenerate requirements.lock from a fresh venv (maintainers only).
lock:
	@bash scripts/lock.sh

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log .stamps/build .stamps/colcon.log
