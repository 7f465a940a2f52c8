# plantdreamer developer commands. `make help` lists them.
# Every target sets up what it needs from nothing: a fresh .venv, the Rust build, all deps.

SHELL := bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-dev
DEPS := $(VENV)/.installed-dependencies
CORE := $(VENV)/.installed-core
BENCH_STAMP := $(VENV)/.installed-bench
DOCS_STAMP := $(VENV)/.installed-docs
PYTEST_ARGS ?=
# pytest-xdist workers for `make test-python`. Half the suite's time is subprocesses and
# waits, so two workers on 2 cores took it from 494 s to 317 s (measured; tests/conftest.py
# says how the files are shared out).
PYTEST_WORKERS ?= 2
# A pytest run's exit status: 5 (no test collected: PYTEST_ARGS named none of its files) fails
# only when every run collected none, so an empty suite still fails (.ci/run).
PYTEST_STATUS = && status 0 || status $$?

.PHONY: help setup build test test-slow rust-tests test-rust test-python test-wheel wheel browser system-libs demo bench docs lint format clean

help: ## List the developer commands
	@grep -hE '^[a-zA-Z_-]+:.*?## ' $(MAKEFILE_LIST) | \
		awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-12s\033[0m %s\n", $$1, $$2}'

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

# The Cargo profile of the native module in .venv: `release` (thin LTO, one codegen unit:
# what users get) for the demo and the benchmarks; the tests build `ci` (the same code
# without LTO, in parallel codegen units: both cores compile the crate), as the test
# targets below set.
CORE_PROFILE ?= release

# Every build of the native module (the editable install, `make build`, the wheel) is the
# same maturin build: linked by zig against glibc 2.17 (manylinux2014). So the module the
# tests load is the one the wheel ships, and cargo compiles it once for both (the editable
# install runs .venv's own maturin and zig, without pip's build isolation).
BUILD_ARGS = --profile $(CORE_PROFILE) --zig --compatibility manylinux2014
BUILD_PATH = PATH="$(abspath $(VENV))/bin:$$PATH"
# The package alone (its dependencies are installed apart, $(DEPS)). -v: pip passes cargo's
# progress through.
EDITABLE_INSTALL = $(BUILD_PATH) MATURIN_PEP517_ARGS="$(BUILD_ARGS)" \
	$(PY) -m pip install --no-build-isolation --progress-bar off -v --no-deps -e .
BUILD_TOOLS := $(VENV)/.installed-build-tools

# maturin and ziglang, as pyproject.toml pins them (scripts/requirements.py reads them).
$(BUILD_TOOLS): pyproject.toml | $(PY)
	$(PY) scripts/requirements.py > $(VENV)/build-tools.txt
	$(PY) -m pip install --quiet -r $(VENV)/build-tools.txt
	touch $@

# Every runtime + dev dependency and the viewer extra (viser), which the viewer's tests
# use. pip unpacks them (minutes on one core) while cargo compiles the native module (CORE):
# installing the package with its dependencies would build the module first and unpack
# them only after it. --no-compile: pip would byte-compile all 21,000 modules (100 s of one
# core, measured), where Python compiles the few hundred a run imports, once, on import.
# (After the build tools: both lists name maturin and ziglang.)
$(DEPS): pyproject.toml | $(BUILD_TOOLS)
	@echo "pip: installing the dependencies (minutes on one core, beside cargo)"
	$(PY) scripts/requirements.py --dependencies dev viewer > $(VENV)/dependencies.txt
	$(PY) -m pip install --progress-bar off --no-compile -r $(VENV)/dependencies.txt
	touch $@

# The package itself, editable, and its native module (CORE_PROFILE).
$(CORE): pyproject.toml $(BUILD_TOOLS)
	@echo "pip: compiling the native core ($(CORE_PROFILE) profile; minutes on 2 cores)"
	$(EDITABLE_INSTALL)
	touch $@

$(STAMP): $(DEPS) $(CORE)
	touch $@

setup: $(STAMP) system-libs ## Create .venv with plantdreamer (editable), its dev and viewer extras, and the Debian libraries they load

build: $(STAMP) ## Rebuild the native module in place (CORE_PROFILE, release by default)
	@# The module is _core.abi3.so; a version-specific one left by an older build would
	@# shadow it (Python tries _core.cpython-3XY-*.so first).
	rm -f python/plantdreamer/_core.cpython-*.so
	$(EDITABLE_INSTALL)

# `cargo test` also builds the examples (to check they compile), into target/debug/examples:
# tests/test_thread_scaling.py runs the raster_timing one from there.
rust-tests: ## Compile the Rust tests and examples without running them
	cargo test --workspace --no-run

test-rust: ## Run the Rust tests (no Python needed)
	cargo test --workspace

# The suite's two tiers (pyproject's `slow` marker): `make test` runs every test but the
# slow ones, the end-to-end runs that take tens of seconds each on 2 cores (Ray clusters,
# SIGKILL and resume in subprocesses, detectors trained, the demo, the known answer);
# `make test-slow` runs those. CI runs both.
TEST_TIER ?= not slow

test-python: CORE_PROFILE := ci
test-python: build browser system-libs ## Run the Python tests but the slow tier (native module: ci profile)
	@# The Ray files and the known-answer files side by side, each group in one process (its
	@# output follows the other's), then every other file on the workers (tests/conftest.py).
	@failed=0; collected=0; log=$$(mktemp); \
	status() { [ $$1 = 5 ] || collected=1; [ $$1 = 0 ] || [ $$1 = 5 ] || failed=1; }; \
	$(PY) -m pytest -m "$(TEST_TIER)" --file-group ray $(PYTEST_ARGS) >$$log 2>&1 & ray=$$!; \
	$(PY) -m pytest -m "$(TEST_TIER)" --file-group known_answer $(PYTEST_ARGS) $(PYTEST_STATUS); \
	wait $$ray $(PYTEST_STATUS); cat $$log; rm -f $$log; \
	$(PY) -m pytest -m "$(TEST_TIER)" -n $(PYTEST_WORKERS) --file-group other $(PYTEST_ARGS) \
		$(PYTEST_STATUS); \
	if [ $$collected = 0 ]; then echo "no test collected" >&2; exit 5; fi; exit $$failed

test-slow: ## Set up everything, then run the slow tier of the Python tests (CI runs it after `make test`)
	$(MAKE) --no-print-directory -j2 setup CORE_PROFILE=ci
	$(MAKE) --no-print-directory test-python TEST_TIER=slow

browser: ## Install Debian's chromium for the viewer's browser test (when run as root)
	@# The browser test skips, saying why, when no Chromium can be found.
	@if ! command -v chromium >/dev/null; then \
		if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq chromium; \
		else echo "note: install Debian's chromium for the viewer's browser test"; fi; fi

# The shared libraries that Open3D (open3d-cpu) and OpenCV (Ultralytics') load: soname and
# the Debian package that ships it. A fresh Debian 12 image lacks only libusb-1.0-0.
# (grep reads all of ldconfig's list: with -q it could stop early, and pipefail would
# count the broken pipe as a missing library.)
SYSTEM_LIBS := libusb-1.0.so.0:libusb-1.0-0 libgomp.so.1:libgomp1 libGL.so.1:libgl1 \
	libEGL.so.1:libegl1 libgthread-2.0.so.0:libglib2.0-0

system-libs: ## Install Debian's libraries that Open3D and OpenCV load (when run as root)
	@missing=""; for lib in $(SYSTEM_LIBS); do \
		ldconfig -p | grep "$${lib%%:*}" >/dev/null || missing="$$missing $${lib#*:}"; done; \
	if [ -n "$$missing" ]; then \
		if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq $$missing; \
		else echo "note: install Debian's$$missing for the Open3D and Ultralytics tests"; fi; fi

wheel: $(STAMP) ## Build the abi3 wheel (manylinux2014, via zig) and the sdist into dist/
	rm -f dist/plantdreamer-*.whl dist/plantdreamer-*.tar.gz
	@# The venv first on PATH: maturin finds zig as `python -m ziglang` (the dev extra's ziglang).
	$(BUILD_PATH) $(VENV)/bin/maturin build $(BUILD_ARGS) --out dist
	$(VENV)/bin/maturin sdist --out dist

# The check is of the packaging (abi3, manylinux2014 through zig, no Rust needed to run),
# not of LTO: it packs the ci profile's build that the Python tests ran.
test-wheel: CORE_PROFILE := ci
test-wheel: wheel ## Install the wheel (ci profile) in a fresh venv without Rust on PATH and run it
	scripts/check_wheel.sh dist/plantdreamer-*.whl $(PY)
	$(PY) scripts/check_sdist.py dist/plantdreamer-*.tar.gz
	@# Every address in the built wheel and sdist is a reviewed one (tests/test_urls.py).
	PLANTDREAMER_BUILT="$$(echo dist/plantdreamer-*.whl dist/plantdreamer-*.tar.gz)" \
		$(PY) -m pytest -q tests/test_urls.py -k built

# Three jobs at once: the Rust tests and the native module compile (cargo, both cores)
# while pip unpacks the dependencies (one core); then the three test sets run in turn.
test: ## Set up everything, then run the Rust tests, the Python tests but the slow tier, and the wheel check
	$(MAKE) --no-print-directory -j3 rust-tests setup CORE_PROFILE=ci
	$(MAKE) --no-print-directory test-rust test-python test-wheel

# The demo: SDS through the known-answer models the tests use (tests/data/known_answer/: a
# VAE, UNet and depth ControlNet trained on bean seed 0's true views at 64 px), from noise
# colours, scored against the plant's held-out true views. Each run replaces its own files in
# DEMO_OUT (generate's outputs, demo.json, demo.png); anything else there is left alone.
DEMO_OUT ?= out/demo
DEMO_STEPS ?= 200
# Steps between the demo's progress pictures: progress.png shows its 200 steps in 8.
DEMO_PROGRESS ?= 25
DEMO_MODELS := tests/data/known_answer/bean_s0_r64

demo: build ## Run the main job (SDS, tiny committed models) and score it against the truth
	$(PY) -m plantdreamer.known_answer.demo $(DEMO_OUT) -- \
		$(VENV)/bin/plantdreamer generate --species bean --seed 0 --points 100000 \
		--resolution 64 --sds-resolution 64 --color-init noise --guidance sds \
		--base-model $(DEMO_MODELS)/base --controlnet $(DEMO_MODELS)/controlnet \
		--steps $(DEMO_STEPS) --progress-every $(DEMO_PROGRESS) --eval-views 36 \
		--out $(DEMO_OUT) --overwrite

# The bench extra's packages alone (`pip install -e '.[bench]'` would build the core again).
$(BENCH_STAMP): $(STAMP) | system-libs
	$(PY) scripts/requirements.py --dependencies bench > $(VENV)/bench-requirements.txt
	$(PY) -m pip install --progress-bar off -r $(VENV)/bench-requirements.txt
	touch $@

bench: $(BENCH_STAMP) build ## Run the benchmarks and regenerate BENCHMARKS.md
	$(PY) benches/run_all.py

# The docs extra's packages alone: the editable install is there already, and `pip install
# -e '.[docs]'` would build the native module again.
$(DOCS_STAMP): $(STAMP)
	$(PY) scripts/requirements.py --dependencies docs > $(VENV)/docs-requirements.txt
	$(PY) -m pip install --quiet -r $(VENV)/docs-requirements.txt
	touch $@

# mkdocs (strict: a broken link or anchor is an error); the CLI reference is written from
# the click commands (scripts/docs_cli_reference.py) and the API reference from the
# docstrings (mkdocstrings), so the package must import.
docs: $(DOCS_STAMP) ## Build the documentation site into site/, warnings as errors
	$(VENV)/bin/mkdocs build --strict

lint: $(STAMP) docs ## cargo fmt --check, clippy -D warnings, ruff, mypy, the stub's check, the docs site
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests benches scripts examples
	$(VENV)/bin/ruff format --check python tests benches scripts examples
	$(VENV)/bin/mypy python/plantdreamer
	@# _core.pyi describes the compiled module exactly (the module the tests built).
	cd python && ../$(VENV)/bin/python -m mypy.stubtest plantdreamer._core \
		--mypy-config-file ../pyproject.toml

format: $(STAMP) ## Format Rust and Python sources
	cargo fmt --all
	$(VENV)/bin/ruff format python tests benches scripts examples
	$(VENV)/bin/ruff check --fix python tests benches scripts examples

clean: ## Remove build outputs (keeps .venv)
	cargo clean
	rm -f python/plantdreamer/_core*.so
	rm -rf dist
