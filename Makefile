# valve suite: two commands do everything -- `make demo` and `make test`.
# Both run `make setup` first (idempotent: seconds when nothing changed).
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
ROOT := $(abspath $(dir $(lastword $(MAKEFILE_LIST))))
ENV := source $(ROOT)/ros2_ws/env.bash
# Every run keeps DDS on this machine; tests pick their own ROS_DOMAIN_ID per process.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

# make demo BACKEND=can runs the same demo with the CAN driver + controller emulator.
BACKEND ?= sim
# make demo BACKEND=can PROTOCOL=canopen|j1939|dbc: the driver against a stand-in device.
PROTOCOL ?= suite
# make demo CYLINDER=double: the double-acting example; LIVE=1: Foxglove WebSocket view.
CYLINDER ?= single
LIVE ?= 0
DEMO_ARGS ?=
# Two pytest-xdist workers (tests/conftest.py: work units, `serial` tests run alone);
# `make test PYTEST_ARGS=...` replaces this (without -n: one process, as before).
PYTEST_ARGS ?= -n 2 --dist loadgroup --no-loadscope-reorder

.PHONY: help setup demo test bench lint clean distclean

help:
	@echo "make demo     set up (if needed) and run the suite's demo (BACKEND=sim|can, LIVE=1)"
	@echo "make test     set up (if needed) and run all tests"
	@echo "make bench    run the benchmarks, write benchmarks/results.json and docs/benchmarks.md"
	@echo "make setup    only the set-up: venv, pinned ROS 2 wheels, wheel path fix, colcon build"
	@echo "make clean    remove the workspace build; make distclean also removes .venv"

setup:
	@bash $(ROOT)/scripts/setup.sh

demo: setup
	@$(ENV) && valve_demo --backend $(BACKEND) --protocol $(PROTOCOL) --cylinder $(CYLINDER) \
		$(if $(filter 1 yes true,$(LIVE)),--live,) $(DEMO_ARGS)

test: setup
	@$(ENV) && cd $(ROOT) && python -m pytest tests $(PYTEST_ARGS)

bench: setup
	@$(ENV) && cd $(ROOT) && python benchmarks/run_all.py

lint: setup
	@$(ENV) && cd $(ROOT) && python -m flake8 --max-line-length 99 valve_model_pkg valve_driver_pkg valve_bringup tests benchmarks scripts

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log

distclean: clean
	rm -rf .venv
