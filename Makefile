# The two set-up commands a new user needs: `make test` and `make demo`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

ROS_ENV ?= .ros-venv

.PHONY: test test-ros2 demo install

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e ".[all,test]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

# The ROS 2 node under a real rclpy, in an environment of its own (never .venv), each DDS
# process in a loopback-only network namespace (needs root for unshare -n).
test-ros2: $(STAMP)
	bash .ci/ros_env.sh $(ROS_ENV)
	SEGMIN_ROS_ENV=$(abspath $(ROS_ENV)) $(PY) -m pytest -q -m ros2 tests/test_ros2_node.py

demo: $(STAMP)
	$(VENV)/bin/segmin pipeline --config quick --out runs/demo
