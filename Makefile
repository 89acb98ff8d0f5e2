# hyperarm: the two commands are `make demo` and `make test`; both set everything up first.
SHELL := /bin/bash
.DEFAULT_GOAL := help

.PHONY: help setup build demo test test-core lock clean

help:
	@echo "make demo   - set up (idempotent) and run the demo on the mock driver"
	@echo "make test   - set up (idempotent) and run the whole test suite"
	@echo "make setup  - only the set-up (venv or /opt/ros/jazzy, colcon build)"
	@echo "make clean  - remove build products (keeps .venv)"

setup:
	@bash scripts/setup.sh

build: setup

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh $(ARGS)

# Regenerate requirements.lock from a fresh venv (maintainers only).
lock:
	@bash scripts/lock.sh

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log .stamps/build .stamps/colcon.log
