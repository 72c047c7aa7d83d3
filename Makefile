# The two set-up commands a new user needs: `make test` and `make demo`. `make docs` builds the site.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ROS_ENV ?= .ros-venv

.PHONY: test test-ros2 demo install docs lint

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e ".[all,litert-export,test]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

# The ROS 2 node under a real rclpy, in an environment of its own (never .venv), each DDS
# process in a loopback-only network namespace (needs root for unshare -n); the ROS 2 package
# (ros/segmin_ros) built with colcon and its installed node started as its launch file says.
test-ros2: $(STAMP)
	bash .ci/ros_env.sh $(ROS_ENV)
	SEGMIN_ROS_ENV=$(abspath $(ROS_ENV)) $(PY) -m pytest -q -m ros2 tests/test_ros2_node.py tests/test_ros2_package.py

demo: $(STAMP)
	$(VENV)/bin/segmin pipeline --config quick --out runs/demo

# Format, lint and type checks (ruff and mypy; their settings are in pyproject.toml), and vermin:
# every package the wheel ships imports on Python 3.10 (ROS 2 Humble's), the lowest requires-python
# admits. vermin reads the stdlib's history (a 3.11 module, member or syntax fails the check);
# annotations count as evaluated because the config dataclasses resolve theirs at run time.
LINT_STAMP := $(VENV)/.lint-installed
WHEEL_PACKAGES := segmin nav_eval data models train export

$(LINT_STAMP): pyproject.toml | $(STAMP)
	$(PY) -m pip install --quiet -e ".[all,litert-export,test,lint]" vermin==1.9.2
	touch $(LINT_STAMP)

lint: $(LINT_STAMP)
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
	$(VENV)/bin/vermin --target=3.10- --violations --no-tips --eval-annotations $(WHEEL_PACKAGES)

# The documentation site, built strictly (a broken link, image or API reference fails) into site/.
# mkdocstrings reads the package as installed (the package-dir mapping applied) from
# build/docs-src: the repository's folders alone do not show the `segmin.*` layout.
DOCS_STAMP := $(VENV)/.docs-installed
DOCS_SRC := build/docs-src

$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(PY) -m pip install --quiet -e ".[all,test,docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	rm -rf $(DOCS_SRC)
	$(PY) -m pip install --quiet --no-deps --target $(DOCS_SRC) .
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site
