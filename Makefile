# Two commands do everything: `make demo` (the main job) and `make test` (every test).
# Both create .venv/ with the ROS 2 Jazzy wheels from the package index: no ROS install needed.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Every process that touches DDS stays on this machine, on its own domain.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp

.PHONY: venv test lint pytest demo bench paper clean

venv: $(STAMP)

$(STAMP): setup.py package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[wheels,test]'
	touch $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check planar_vo test

pytest: $(STAMP)
	ROS_PYTHON_CHECK_FIELDS=1 $(VENV)/bin/pytest -q test

test: lint pytest

paper: $(STAMP)
	mkdir -p out
	$(VENV)/bin/planar_vo_paper_experiment --plot out/paper_fig5.png

demo: paper

bench: $(STAMP)

clean:
	rm -rf $(VENV) build install log out *.egg-info
