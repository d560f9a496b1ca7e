# SPDX-License-Identifier: Apache-2.0
# Every target creates .venv on first use; nothing outside the work tree is touched.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# The upstream ROS 2 `ros2` CLI and `ros2 launch`, built into .venv from the sources in
# ../shared/ros2-tools when no system `ros2` (a real Jazzy install) is on the PATH. The
# install script is idempotent (a second run changes nothing, in about a second) and
# writes only into .venv and TMPDIR, never into ../shared.
ROS2_TOOLS ?= ../shared/ros2-tools

.PHONY: venv ros2-tools demo test test-fast bench lint clean

# The tests start several hundred Python processes (nodes, bringup, the CLI), each of which
# compiled the package from source where the environment sets PYTHONDONTWRITEBYTECODE
# (0.25 s a process here): the tests' bytecode is cached in .pycache/ of this work tree.
TEST_ENV := PYTHONDONTWRITEBYTECODE= PYTHONPYCACHEPREFIX=$(CURDIR)/.pycache

venv: $(STAMP) ros2-tools

$(STAMP): setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test,bench,hardware,live,records]'
	touch $(STAMP)

ros2-tools: $(STAMP)
	@sys_ros2=$$(command -v ros2 || true); \
	if [ -n "$$sys_ros2" ] && [ "$$sys_ros2" != "$(CURDIR)/$(VENV)/bin/ros2" ]; then \
	  echo "make: using the system ros2 ($$sys_ros2)"; \
	elif [ -f "$(ROS2_TOOLS)/install" ]; then \
	  bash "$(ROS2_TOOLS)/install" $(VENV) || echo "make: warning: installing" \
	    "$(ROS2_TOOLS) failed (see above): the ros2 CLI tests will skip (fail in CI)" >&2; \
	else \
	  echo "make: warning: no ros2 on the PATH and no $(ROS2_TOOLS)/install:" \
	       "the ros2 CLI tests will skip (fail in CI)" >&2; \
	fi

demo: $(STAMP)
	$(PY) -m fiber_align.demo

# Everything: the pure tests on every core (pytest-xdist), then the `ros` ones (rclpy
# nodes, graphs, any child process) one after the other: one graph at a time, as the
# realtime runs need the machine's cores. The slowest 25 are listed: where the suite's time
# goes (16 of its 17 minutes are these, one after the other).
test: venv
	$(TEST_ENV) $(PY) -m pytest -q -n auto -m "not ros" test; pure=$$?; \
	$(TEST_ENV) $(PY) -m pytest -q -m ros --durations=25 test; ros=$$?; \
	[ $$pure -eq 0 ] && [ $$ros -eq 0 ]

# The pure tests only: no rclpy, no process (test/conftest.py fails a test that starts one
# without the `ros` marker), so no ROS graph and no lock; on every core.
test-fast: $(STAMP)
	$(TEST_ENV) $(PY) -m pytest -q -n auto -m "not ros" test

bench: $(STAMP)
	$(PY) -m bench

lint: $(STAMP)
	$(PY) -m pytest -q test/test_flake8.py test/test_pep257.py

clean:
	rm -rf $(VENV) build install log *.egg-info .pycache
