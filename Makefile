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
# numpy's BLAS on one thread, as planar_vo sets where it is imported first (not pytest, which
# loads numpy before it): its small problems gain nothing from more, and lose on busy cores.
export OPENBLAS_NUM_THREADS ?= 1
# The venv's console scripts (planar_vo_node, started by demo and bench) are found on PATH.
export PATH := $(abspath $(VENV))/bin:$(PATH)

.PHONY: venv test lint pytest demo bench soak paper mountings terrain clean

venv: $(STAMP)

$(STAMP): setup.py package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[wheels,test]'
	touch $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check planar_vo test launch

pytest: $(STAMP)
	ROS_PYTHON_CHECK_FIELDS=1 $(VENV)/bin/pytest -q test

test: lint pytest

# The main job: the node on the bundled bag over loopback DDS, scored against ground truth.
demo: $(STAMP)
	mkdir -p out
	$(VENV)/bin/planar_vo_demo bags/default --plot out/demo.png --log out/demo_node.log

# Speed as ratios against baselines measured in the same run (never a pass/fail timing):
# the bundled bag (and the node over DDS), then a 752x480 camera (rendered once into out/),
# the same with a rolling shutter, and uneven road: all four terrains under a sprung body.
BENCH_752 := out/bench_752x480
# Each also prints the front end's cost against its accuracy (--curve); the bundled bag's run
# the node's latency, CPU per frame and highest sustained rate, quiet and with a core busy.
bench: $(STAMP)
	$(VENV)/bin/planar_vo_bench bags/default --live --curve
	mkdir -p out
	test -d $(BENCH_752) || $(VENV)/bin/planar_vo_synth $(BENCH_752) --width 752 --height 480 \
		--rate 15 --frames 90 --noise 1.0 --quiet
	$(VENV)/bin/planar_vo_bench $(BENCH_752) --curve
	# A rolling-shutter camera (30 ms readout): the same drive, the readout modelled.
	test -d $(BENCH_752)_rs || $(VENV)/bin/planar_vo_synth $(BENCH_752)_rs --width 752 \
		--height 480 --rate 15 --frames 90 --noise 1.0 --rolling-shutter 0.03 --quiet
	printf 'planar_vo:\n  ros__parameters:\n    rolling_shutter_readout: 0.03\n' > out/rs_params.yaml
	$(VENV)/bin/planar_vo_bench $(BENCH_752)_rs --params out/rs_params.yaml
	# Grades, bumps, camber and hills under a sprung body (`make terrain`'s drive): what the
	# local ground's bands, bumps and jolts cost a frame.
	$(MAKE) $(ALL_SPRUNG)
	$(VENV)/bin/planar_vo_bench $(ALL_SPRUNG) --params $(ALL_SPRUNG).yaml

# Long runs over DDS (about 9 minutes, not part of `make test`) on a 752x480 drive (600 frames,
# rendered once into out/), played forward and backward: SOAK_FRAMES at 60 Hz (>= 99.5 %
# answered), then at 30 Hz with one core kept busy by another process (>= 99 %); each prints
# frames answered, the node's CPU per frame and its resident memory over time.
SOAK_752 := out/soak_752x480
SOAK_FRAMES ?= 10000
soak: $(STAMP)
	mkdir -p out
	test -d $(SOAK_752) || $(VENV)/bin/planar_vo_synth $(SOAK_752) --width 752 --height 480 \
		--frames 600 --noise 1.0 --quiet
	status=0; \
	$(VENV)/bin/planar_vo_soak $(SOAK_752) --frames $(SOAK_FRAMES) --rate 60 \
		--min-answered 99.5 || status=1; \
	$(VENV)/bin/planar_vo_soak $(SOAK_752) --frames $(SOAK_FRAMES) --rate 30 --busy 1 \
		--min-answered 99 || status=1; \
	exit $$status

# The paper's Monte Carlo experiment (Fig. 5), extended with OpenCV's 5- and 4-point methods.
paper: $(STAMP)
	mkdir -p out
	$(VENV)/bin/planar_vo_paper_experiment --plot out/paper_fig5.png

# The sprung-body tables of the README: car and rough bodies against a rigid mount and
# against OpenCV's homography on the same tracks (four 46 m drives each, about 10 minutes).
mountings: $(STAMP)
	$(VENV)/bin/planar_vo_mounting_experiment --scenario car
	$(VENV)/bin/planar_vo_mounting_experiment --scenario rough

# The terrain table of docs/terrain.md: 300-frame drives at 20 Hz, 752x480 over each kind of
# terrain (rendered once into out/terrain, a few minutes each), replayed with the shipped
# defaults and only the nominal mounting; then two of its "Not solved" (a body pitching about
# base_link, 3 m road humps). `make terrain TERRAIN_SEED=N` renders other drives of each kind
# (into out/terrain_seedN): drives the defaults were not tuned on.
TERRAIN_SEED ?= 0
TERRAIN_OUT := $(if $(filter 0,$(TERRAIN_SEED)),out/terrain,out/terrain_seed$(TERRAIN_SEED))
SPRUNG_BODY := --body-pitch 1.0 --body-roll 0.6 --bounce 0.015
TERRAIN_CAMERA := --width 752 --height 480 --rate 20 --frames 300 --camera-height 1.1 \
	--camera-x 1.2 --dist -0.28 0.07 0.0005 -0.0005 0 --quiet
ALL_SPRUNG := out/terrain/all_sprung
$(ALL_SPRUNG): | $(STAMP)
	mkdir -p out/terrain
	$(VENV)/bin/planar_vo_synth $@ --terrain all $(TERRAIN_CAMERA) $(SPRUNG_BODY) \
		--params-out $@.yaml

terrain: $(STAMP)
	mkdir -p $(TERRAIN_OUT)
	status=0; \
	for case in "flat flat" "grades grades" "bumps bumps" "camber camber" "hills hills" \
			"all all" "sprung flat $(SPRUNG_BODY)" "all_sprung all $(SPRUNG_BODY)" \
			"miscal flat --configured-error pitch=1,roll=1,yaw=1,x=0.15" \
			"sprung_about_base_link flat $(SPRUNG_BODY) --body-pivot 0 0" \
			"humps_3m bumps --terrain-shape bump_length=3.0"; do \
		set -- $$case; name=$$1; kind=$$2; shift 2; \
		out=$(TERRAIN_OUT)/$$name; \
		test -d $$out || $(VENV)/bin/planar_vo_synth $$out --terrain $$kind \
			--seed $(TERRAIN_SEED) $(TERRAIN_CAMERA) "$$@" --params-out $$out.yaml \
			|| { echo "== $$name: not rendered (above), next"; status=1; continue; }; \
		echo "== $$name"; \
		$(VENV)/bin/planar_vo_replay $$out --params $$out.yaml || status=1; \
	done; \
	exit $$status

clean:
	rm -rf $(VENV) build install log out *.egg-info
