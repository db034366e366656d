# pcv_sim developer entry points: `make run`, `make test` (see README.md).
#
#   make test DISTRO=jazzy PYTEST_ARGS='-k layout -x'
#
# Each ROS 2 distribution gets its own venv (.venv-kilted, .venv-jazzy) built from
# requirements/$(DISTRO).txt, with ROS 2 from the PyPI wheels (ros-* / ros-jazzy-*).
# The binary ROS wheels are cp311 only: PYTHON must be a Python 3.11.
#
# What `pip install -e .` does with setup.cfg's [develop]/[install] sections (checked in
# fresh venvs, setuptools 79.0.1 with --no-build-isolation and setuptools 84 with build
# isolation): nothing. pip builds a PEP 660 editable wheel, so `script_dir` and
# `install_scripts` = $base/lib/pcv_sim are ignored and pip writes the console scripts
# (pcv-sim, emulator, demo) to $(VENV)/bin; the package is importable through a
# __editable__ .pth finder and `python -m pcv_sim` works (given pcv_sim/__main__.py).
# data_files (share/...) are NOT installed by an editable install; a plain `pip install .`
# installs them under $(VENV)/share and also puts scripts in bin/. Only colcon
# (`setup.py install` under the hood) honours setup.cfg and puts them in lib/pcv_sim,
# which is what `ros2 run` needs; test/test_package_layout.py checks that with a real
# colcon build. Make targets therefore always use `$(VENV)/bin/python -m ...`.
# --no-build-isolation builds with the venv's pinned setuptools (<80, as colcon needs)
# and, with setuptools 79, leaves no pcv_sim.egg-info in the checkout.
#
# ros_wheels_bootstrapper (a .pth file) re-executes the interpreter once to set
# LD_LIBRARY_PATH and marks that with _ROS_WHEELS_BOOTSTRAP_COMPLETE=1. Inherited from
# another interpreter that mark makes our venv's python skip its bootstrap (rclpy then
# fails with librcl_action.so not found), so it is never passed on from make.

DISTRO ?= kilted
ifeq ($(filter $(DISTRO),kilted jazzy),)
$(error DISTRO must be 'kilted' or 'jazzy', not '$(DISTRO)')
endif
ifneq ($(words $(DISTRO)),1)
$(error DISTRO must be exactly one of 'kilted' or 'jazzy', not '$(DISTRO)')
endif

PYTHON ?= python3
VENV := .venv-$(DISTRO)
VENV_PY := $(VENV)/bin/python
STAMP := $(VENV)/.pcv_sim-installed
REQUIREMENTS := requirements/$(DISTRO).txt
PYTEST_ARGS ?=

unexport _ROS_WHEELS_BOOTSTRAP_COMPLETE

.PHONY: venv run rig demo test bench clean

venv: $(STAMP)

$(STAMP): $(REQUIREMENTS) requirements/common.txt setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(VENV)
	$(VENV_PY) -m pip install --quiet --upgrade pip
	$(VENV_PY) -m pip install --quiet -r $(REQUIREMENTS)
	$(VENV_PY) -m pip install --quiet --no-build-isolation -e .
	touch $@

run: venv
	$(VENV_PY) -m pcv_sim.node.emulator --ros-args --params-file config/emulator.yaml

# The rig: the valves and the steering cylinder of config/rig.yaml in one node (lockstep, simulated
# time by default: it waits for a controller's commands for every valve each period).
rig: venv
	$(VENV_PY) -m pcv_sim.node.rig

# Drives a duty step sequence against an emulator already running (`make run` in another
# terminal) and prints what it saw; starts nothing itself. DEMO_ARGS='--namespace /left'.
demo: venv
	$(VENV_PY) -m pcv_sim.node.demo $(DEMO_ARGS)

test: venv
	$(VENV_PY) -m pytest -q test $(PYTEST_ARGS)

bench: venv
	$(VENV_PY) bench/run_all.py

clean:
	rm -rf .venv-kilted .venv-jazzy build install log .pytest_cache pcv_sim.egg-info
	find . -name __pycache__ -type d -not -path './.venv*' -prune -exec rm -rf {} +
