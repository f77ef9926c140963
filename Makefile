# ICGT: every command a developer or CI needs. `make test` and `make demo` set up what is
# missing themselves (venv, Python packages, CMake build); system packages come from .ci/run.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
BUILD  := build/host
FUZZ_BUILD := build/fuzz
CLANGXX ?= $(shell command -v clang++-14 || command -v clang++)
RUFF   := $(VENV)/bin/ruff check --config host/pyproject.toml
PY_SOURCES := host tests protocol benchmarks

.PHONY: all test test-fast demo bench build venv generate vectors lint fuzz clean help
# pytest-xdist: one worker per core; a module's tests, and the modules sharing a session flight, stay on
# one worker (tests/conftest.py), so each simulated flight is flown once.
PYTEST := ICGT_BUILD_DIR=$(BUILD) $(VENV)/bin/pytest -q --timeout 600 -p no:cacheprovider -n auto --dist loadgroup
# The inner loop's Python tests: none of them flies the simulator in real time.
FAST_TESTS := tests/clocks tests/conformance tests/device tests/geometry tests/geotag tests/host tests/sync \
  tests/recorder/test_config_schema.py tests/recorder/test_step_schedule.py tests/recorder/test_payloads.py \
  tests/report/test_report_units.py tests/export/test_export_units.py tests/mapping/test_mapping_units.py \
  tests/ingest/test_ingest_match_properties.py::test_random_cards_never_pair_wrongly \
  tests/ingest/test_ingest_match_properties.py::test_centisecond_cards_pair_every_image \
  tests/mavlink/test_udp_arrival_stamps.py tests/sim/test_sim_geodesy.py tests/sim/test_sim_trajectory.py

all: test

help:
	@echo "make test   - build everything and run every C++ and Python test"
	@echo "make test-fast - the inner loop: lint, the C++ tests, the Python unit tests (no simulated flight)"
	@echo "make demo   - run the main job on the simulated hardware"
	@echo "make bench  - print benchmark figures next to their peers"
	@echo "make generate / make vectors - rewrite generated code / test vectors after editing protocol/messages.toml"

$(VENV)/.installed: host/pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "icgt needs Python 3.11 or newer; \
	$(PYTHON) is $$($(PYTHON) --version 2>&1). On Ubuntu 22.04: apt-get install python3.11 python3.11-venv, \
	then make PYTHON=python3.11"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e 'host[dev]'
	touch $@

venv: $(VENV)/.installed

build:
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Debug -DICGT_SANITIZE=ON > /dev/null
	cmake --build $(BUILD)

generate:
	$(PYTHON) protocol/generate.py

vectors: venv
	$(PY) protocol/make_vectors.py

lint: venv
	$(PYTHON) protocol/generate.py --check
	$(PY) protocol/make_vectors.py --verify
	$(RUFF) $(PY_SOURCES)
	$(VENV)/bin/ruff format --config host/pyproject.toml --check $(PY_SOURCES)
	$(VENV)/bin/mypy --config-file host/pyproject.toml host/icgt

# libFuzzer on the C++ stream decoder, seeded with the shared vectors; bounded so it fits CI.
fuzz:
	@test -n "$(CLANGXX)" || { echo "clang++ not found: run .ci/run or apt-get install clang-14 libclang-rt-14-dev"; exit 1; }
	mkdir -p $(FUZZ_BUILD)/corpus
	$(CLANGXX) -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -Ifirmware/lib -Ifirmware/lib/protocol \
	  firmware/test/fuzz/fuzz_stream_decoder.cpp firmware/lib/protocol/*.cpp -o $(FUZZ_BUILD)/fuzz_stream_decoder
	cp protocol/vectors/*/*.bin $(FUZZ_BUILD)/corpus/
	$(FUZZ_BUILD)/fuzz_stream_decoder -runs=200000 -max_len=2048 -seed=1 $(FUZZ_BUILD)/corpus

# Cortex-M4/M7 builds of the core with flash/RAM budgets, heap and QEMU boot checks; the
# Teensy board layer against a fake Teensyduino API; no Arduino header outside the board layer.
.PHONY: firmware-checks
firmware-checks:
	firmware/cross/check_no_arduino.sh --self-test
	firmware/cross/check_no_arduino.sh
	firmware/cross/build.sh cortex-m4 cortex-m7
	firmware/cross/check_board_layer.sh
	firmware/cross/isr_stamp_latency.sh

test: venv build lint fuzz firmware-checks
	ctest --test-dir $(BUILD) --output-on-failure
	$(PYTEST) tests
	.ci/min_versions.sh

# Under two minutes: what a change most often breaks, without the real-time flights, fuzzing or cross builds.
test-fast: venv build lint
	ctest --test-dir $(BUILD) --output-on-failure
	$(PYTEST) $(FAST_TESTS)

# The lower bounds of host/pyproject.toml installed exactly, in build/venv-min, with the export tests.
.PHONY: min-versions
min-versions:
	.ci/min_versions.sh

# Figures next to their peers, measured in the same run (shared, noisy machines: not timed tests).
bench: venv build
	$(PY) benchmarks/protocol_decode.py
	$(PY) benchmarks/clock_sync.py
	$(PY) benchmarks/mcap_write.py
	$(PY) benchmarks/recorder_flight.py --scenario deck_pass --out bench-out/recorder
	$(PY) benchmarks/geotag_write.py
	$(PY) benchmarks/recorder_cpu.py --out bench-out/recorder_cpu
	$(PY) benchmarks/damage_map.py --skip-1h
	$(PY) benchmarks/mavsdk_camera.py --out bench-out/mavsdk_camera
	$(PY) benchmarks/resend_faults.py --out bench-out/resend_faults

clean:
	rm -rf build $(VENV) demo-out

# The main job on simulated hardware: the pier-scan scenario recorded, started and stopped from a
# ground station over MAVLink, and scored against ground truth (results in demo-out/).
demo: venv build
	$(VENV)/bin/icgt demo --scenario pier_scan --out demo-out
