# Induction-motor drive stack: one entry point for setup, build, demo, tests and benchmarks.
# Every target creates the virtual environment and builds the workspace first, and is idempotent.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
VPY := $(VENV)/bin/python
DEPS_STAMP := $(VENV)/.deps-installed
BUILD_STAMP := install/.built
SRC_FILES := $(shell find src -type f -not -path '*/__pycache__/*' 2>/dev/null)
# ROS environment for every command below: the workspace overlay on top of the venv.
# The DDS domain is left to the user (ROS_DOMAIN_ID); the in-process tools pick their own.
RUN := source $(VENV)/bin/activate && source install/setup.bash &&

.PHONY: all setup build demo test test-fast fuzz bench bench-table reproduce readme study sensitivity robust-examples robust-study motors motors-drift campaign efficiency gains policy clean distclean

all: demo

setup: $(DEPS_STAMP)

$(DEPS_STAMP): requirements.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (the ROS 2 Jazzy wheels need CPython 3.11)"; exit 1; }
	@test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --disable-pip-version-check -q --upgrade pip
	$(VPY) -m pip install --disable-pip-version-check -q -r requirements.txt
	@touch $@

build: $(BUILD_STAMP)

$(BUILD_STAMP): $(DEPS_STAMP) $(SRC_FILES)
	source $(VENV)/bin/activate && colcon --log-base log build --base-paths src \
	    --event-handlers console_cohesion- summary+ status- 2>&1 | tail -n 3
	@# the real plant's compiled period (numba) into the install's cache: no node compiles it
	$(RUN) python -c 'from im_plant import real_plant_kernel as k; k.warm()'
	@touch $@

# Main job: a full drive scenario, recorded to MCAP, with its report.
demo: build
	$(RUN) ros2_run() { "$$(python -c 'import sys; from ament_index_python.packages import get_package_prefix as p; print(p(sys.argv[1]))' $$1)/lib/$$1/$$2" "$${@:3}"; }; \
	ros2_run im_bringup scenario --task position --strategy min_loss --duration 2.0 --record bags/demo.mcap --force --report bags/demo_report

# Both run the tests on every core (pytest-xdist: -n auto, at most 4 workers), a test file a
# worker so its module fixtures are built once; make test took 21 min serially on a quiet 2-core
# machine, 14 min this way.
XDIST := -n auto --maxprocesses 4 --dist loadfile

test: build
	$(RUN) python -m pytest -q $(XDIST) tests src

# The edit-test loop: every test but those that start processes or take 3 s or more (the marks
# in pytest.ini); CI runs make test, all of them.
test-fast: build
	$(RUN) python -m pytest -q $(XDIST) tests src -m "not processes and not slow"

# Property-based fuzzing of every reader of user input (tests/test_fuzz_*.py) with the 'fuzz'
# hypothesis profile (tests/conftest.py): at least 1,000 fresh cases a property instead of make
# test's 200 seeded ones; one line a property as it ends, then the cases each one ran.
fuzz: build
	$(RUN) HYPOTHESIS_PROFILE=fuzz python -m pytest -v tests/test_fuzz_*.py \
	    --hypothesis-show-statistics

# Benchmark-only dependencies (Ray, measured against Dask) go into the same venv.
bench: build
	$(VPY) -m pip install --disable-pip-version-check -q -r benchmarks/requirements.txt
	$(RUN) python benchmarks/run_all.py

# Three make bench runs (benchmarks/results/run1..3), then the opening table of
# docs/benchmarks.md from their summaries: today's figures against their targets.
bench-table: build
	$(VPY) -m pip install --disable-pip-version-check -q -r benchmarks/requirements.txt
	for i in 1 2 3; do $(RUN) python benchmarks/run_all.py --out benchmarks/results/run$$i || exit 1; done
	$(RUN) python benchmarks/today.py benchmarks/results/run{1,2,3}/summary.json --doc docs/benchmarks.md

# Also refreshes the committed summary docs/results.md and the README's headline are generated from (make readme).
reproduce: build
	$(RUN) python -m im_studies.reproduce --out bags/reproduce
	mkdir -p docs/data && cp bags/reproduce/summary.json docs/data/reproduce_summary.json

# The generated blocks: docs/results.md (status markers) and the README's headline (headline markers)
# from docs/data/reproduce_summary.json; the topic and parameter tables of docs/parameters.md from the code;
# the run, motor and efficiency-map files' JSON Schemas from their models.
readme: build
	$(RUN) python -m im_studies.readme_status --summary docs/data/reproduce_summary.json --results docs/results.md --readme README.md --write
	$(RUN) python -m im_studies.docs docs/parameters.md
	$(RUN) python -m im_studies.schemas

# Chapter-3 study on the ROS-free loop (energy table, sampled-data limit, core-loss exponent),
# the drive on the real plant (docs/compensation.md), under the delay (docs/plant.md §10), and
# the thesis law beside the drive industry's (docs/baselines.md).
study: build
	$(RUN) python -m im_studies.study --out bags/study
	$(RUN) python -m im_studies.study_real_plant --json bags/study/real_plant.json --plots bags/study
	$(RUN) python -m im_studies.study_delay --json bags/study/delay.json
	$(RUN) python -m im_studies.study_compare --json docs/data/compare.json --plot docs/figures/compare.png --doc docs/comparison.md

# Seed 000 §4.2.1 sensitivity of the nominal controller, and §4.3 nominal vs adaptive (offline).
sensitivity: build
	$(RUN) python -m im_studies.study_ch4 --part sensitivity --out bags/sensitivity

robust-examples: build
	$(RUN) python -m im_robust.cli examples --out bags/robust

# Seed 001 applied to the drive: certified gains vs the thesis's at 1 ms and 100 µs (offline loop).
robust-study: build
	$(RUN) python -m im_studies.robust_study --out bags/robust_study

# Every shipped motor (share/im_common/config/motors) through rating-scaled tasks (offline loop).
motors: build
	$(RUN) python -m im_studies.study_motors --out bags/motors

# The same motors under the chapter-4 drift scaled to each (nominal, adaptive feeds, truth-fed).
motors-drift: build
	$(RUN) python -m im_studies.study_motors --drift --out bags/motors

# Monte Carlo campaign over the parameter box (docs/campaign.md): 200 motors, certified 1 ms gains
# at 1 kHz and the thesis's gains at 4 kHz, on a local Dask cluster of every core. Resumes when
# interrupted; CAMPAIGN_ARGS passes more options (e.g. --address tcp://HOST:8786, --force).
campaign: build
	$(RUN) python -m im_studies.campaign src/im_bringup/config/campaign.yaml --out bags/campaign $(CAMPAIGN_ARGS)

# The whole drive's efficiency maps of both shipped motors, 10 x 10 and the IEC 61800-9-2
# points, every drive of the run files' compare lists (docs/efficiency.md; resumable)
efficiency: build
	$(RUN) for m in thesis krause_3hp; do python -m im_studies.efficiency_map \
	    src/im_bringup/config/runs/efficiency_$$m.yaml --speeds 10 --torques 10 \
	    --out bags/efficiency_$$m || exit 1; done

# The certified gains shipped for free_run at each rate the pre-flight probe may name
# (250 Hz, 500 Hz, 1 kHz, 2 kHz: src/im_bringup/config/gains_4ms.yaml ... gains_0.5ms.yaml).
gains: build
	$(RUN) design_gains() { "$$(python -c 'from ament_index_python.packages import get_package_prefix as p; print(p("im_controller"))')/lib/im_controller/design_gains" "$$@"; }; \
	for ms in 4 2 1 0.5; do design_gains --period $${ms}e-3 --out src/im_bringup/config/gains_$${ms}ms.yaml || exit 1; done

# The SROS2 access-control policy, generated from the nodes (src/im_bringup/config/sros2/policy.xml).
policy: build
	$(RUN) python -m im_bringup.sros2_policy --write

clean:
	rm -rf build install log

distclean: clean
	rm -rf $(VENV)
