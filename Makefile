# eit_skin on a plain Python machine: `make demo` and `make test` do all set-up.
#
# Set-up is incremental and idempotent: a virtual environment in .venv with the
# pinned wheels of requirements.txt (ROS 2 Kilted included), the interface
# package eit_skin_msgs built by CMake into that environment, and eit_skin
# installed editable. A second run finds everything up to date in seconds.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
PYTHON ?= python3
VENV := $(CURDIR)/.venv
BIN := $(VENV)/bin
BUILD := $(CURDIR)/build
UV := VIRTUAL_ENV=$(VENV) $(BIN)/uv
GENERATOR := $(if $(shell command -v ninja),-G Ninja,)

# ROS environment for everything run from here: the venv is the ament prefix,
# logs stay in build/ (never ~/.ros), DDS discovery stays on this machine.
export AMENT_PREFIX_PATH := $(VENV)
export ROS_LOG_DIR := $(BUILD)/ros_log
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export EIT_SKIN_CACHE ?= $(BUILD)/cache
# Bytecode of every module (the venv's, eit_skin's, the tests') in build/pycache: never a
# __pycache__ in the source tree, and no process compiles eit_skin's modules again.
export PYTHONPYCACHEPREFIX := $(BUILD)/pycache

.PHONY: setup demo test lint bench colcon clean
.DEFAULT_GOAL := demo

# The set-up steps run two at a time (the message build beside ros2-tools' builds).
SETUP_STAMPS := $(VENV)/.stamp-pycache

setup:
	@$(MAKE) --no-print-directory -s -j2 $(SETUP_STAMPS)

$(BIN)/python:
	@echo "[setup] creating virtual environment in .venv"
	@$(PYTHON) -m venv $(VENV)

$(BIN)/uv: | $(BIN)/python
	@echo "[setup] installing uv"
	@$(BIN)/pip install --quiet --disable-pip-version-check "$$(grep -E '^uv==' requirements.txt)"

$(VENV)/.stamp-deps: requirements.txt | $(BIN)/uv
	@echo "[setup] installing pinned dependencies (requirements.txt)"
	@$(UV) pip install --quiet -r requirements.txt
	@touch $@

$(VENV)/.stamp-msgs: $(VENV)/.stamp-deps msg/CMakeLists.txt msg/package.xml $(wildcard msg/*.msg)
	@echo "[setup] building eit_skin_msgs (CMake, log in build/msgs.log)"
	@mkdir -p $(BUILD)
	@{ cmake -S msg -B $(BUILD)/msgs $(GENERATOR) -DCMAKE_INSTALL_PREFIX=$(VENV) \
	    -DBUILD_TESTING=OFF -DPython3_EXECUTABLE=$(BIN)/python \
	  && cmake --build $(BUILD)/msgs -j 2 && cmake --install $(BUILD)/msgs; } \
	  > $(BUILD)/msgs.log 2>&1 || { tail -30 $(BUILD)/msgs.log; exit 1; }
	@touch $@

$(VENV)/.stamp-package: $(VENV)/.stamp-msgs setup.py setup.cfg package.xml
	@echo "[setup] installing eit_skin (editable)"
	@$(UV) pip install --quiet --no-deps -e .
	@touch $@

# uv installs without compiling: so without this step the first processes compiled the
# venv's modules (0.7 s of CPU per node start, over hundreds of node processes in the tests;
# and a fresh venv's first processes all compiling at once is when one crashed once, in
# compile()), and eit_skin's own modules (0.13 s more per process) into PYTHONPYCACHEPREFIX
# (above). Once, after the last installer; files that are not Python 3 (templates) are
# skipped. A module changed later is compiled again by the first process that imports it.
$(VENV)/.stamp-pycache: $(VENV)/.stamp-package
	@echo "[setup] compiling the venv's and eit_skin's modules to bytecode (build/pycache)"
	@$(BIN)/python -m compileall -q -j 2 $(VENV)/lib eit_skin > $(BUILD)/bytecode.log 2>&1 || true
	@touch $@

# launch, launch_testing, launch_ros, tf2_msgs and the ros2 CLI (not on PyPI) from
# ../shared/ros2-tools when that folder exists; without it the launch tests skip.
ROS2_TOOLS := $(abspath $(CURDIR)/../shared/ros2-tools)
ifneq ($(wildcard $(ROS2_TOOLS)/install.sh),)
SETUP_STAMPS += $(VENV)/.stamp-ros2-tools
# one installer into the venv at a time: eit_skin's after ros2-tools'
$(VENV)/.stamp-package: | $(VENV)/.stamp-ros2-tools

$(VENV)/.stamp-ros2-tools: $(VENV)/.stamp-deps $(ROS2_TOOLS)/install.sh
	@echo "[setup] installing launch, launch_testing and ros2 (log in build/ros2-tools.log)"
	@mkdir -p $(BUILD)
	@$(ROS2_TOOLS)/install.sh $(VENV) > $(BUILD)/ros2-tools.log 2>&1 \
	  || { tail -30 $(BUILD)/ros2-tools.log; exit 1; }
	@touch $@
endif

demo: setup
	$(BIN)/eit-skin run --out $(BUILD)/demo

# pytest workers: each test file on one worker so its module fixtures are built once; every
# worker claims its own DDS domain (test/conftest.py). Two workers use both cores of our
# machines (one process left one half idle); TEST_WORKERS=1 gives one process.
# Every test has a time budget (pytest.ini: 60 s, longer ones marked on the test); TEST_TIMEOUT
# changes the default for this run.
TEST_WORKERS ?= 2
TEST_TIMEOUT ?=
test: setup $(VENV)/.stamp-chromium
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile $(if $(TEST_TIMEOUT),--timeout $(TEST_TIMEOUT))

# The designer's browser tests drive a real headless Chromium: the Debian package, installed
# here (as root, where apt-get exists) when it is missing; elsewhere those tests skip and
# say why. Once per venv (delete the stamp to try again).
$(VENV)/.stamp-chromium: | $(BIN)/python
	@if command -v chromium >/dev/null 2>&1; then :; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  echo "[setup] installing chromium for the browser tests (apt-get, log in build/chromium.log)"; \
	  mkdir -p $(BUILD); \
	  { apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y chromium; } \
	    > $(BUILD)/chromium.log 2>&1 \
	    || echo "[setup] chromium could not be installed (build/chromium.log): browser tests skip"; \
	else echo "[setup] no chromium and no apt-get as root: the browser tests skip"; fi
	@touch $@

lint: setup
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

# The standing benchmarks (bench/REPORT.md), one after another, as modules of the bench package.
bench: setup
	@for script in bench/standing/bench_*.py; do module=$${script%.py}; module=$${module//\//.}; \
	  echo "== $$module"; $(BIN)/python -m $$module; done

# Build both packages the way a robot does (into build/colcon, not the venv).
colcon: setup
	cd $(BUILD) && rm -rf colcon && mkdir colcon && cd colcon && \
	  $(BIN)/colcon --log-base log build --base-paths $(CURDIR) $(CURDIR)/msg \
	  --build-base build --install-base install

clean:
	rm -rf $(BUILD) $(VENV)
