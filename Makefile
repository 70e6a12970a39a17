# CAN <-> Zenoh bridge test bench. `make help` lists the targets.
SHELL := /bin/bash
.DEFAULT_GOAL := help

BUILD      ?= build
PYTHON     ?= python3
UCAN_BUILD := $(BUILD)/ucan
PYTEST     := $(PYTHON) -m pytest

.PHONY: help ucan ucan-asan check check-ucan check-bus fuzz-ucan bench-bus test clean

help:
	@echo "make test     run the bench's scenarios against the bridge (the main job)"
	@echo "make check    the project's own tests (unit, bus conformance, fuzz, integration)"
	@echo "make ucan     build the userspace CAN bus (hub, preload library, ucanctl)"
	@echo "make bench-bus  userspace bus throughput/latency benchmark (not part of check)"
	@echo "make clean    remove build/"

ucan:
	cmake -S ucan -B $(UCAN_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
	ninja -C $(UCAN_BUILD)

ucan-asan:
	cmake -S ucan -B $(BUILD)/ucan-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DUCAN_SANITIZE=ON >/dev/null
	ninja -C $(BUILD)/ucan-asan

check-ucan: ucan ucan-asan
	ctest --test-dir $(UCAN_BUILD) --output-on-failure
	ctest --test-dir $(BUILD)/ucan-asan --output-on-failure

# The conformance suite against the release hub, then against the ASan/UBSan hub
# (the preload library is never sanitized: it lives inside arbitrary programs).
check-bus: ucan ucan-asan
	UCAN_BUILD=$(UCAN_BUILD) $(PYTEST) -q tests/bus
	UCAN_BUILD=$(CURDIR)/$(BUILD)/ucan-asan $(PYTEST) -q tests/bus

FUZZ_SECONDS ?= 30
fuzz-ucan:
	cmake -S ucan -B $(BUILD)/ucan-fuzz -G Ninja -DCMAKE_C_COMPILER=clang -DUCAN_FUZZ=ON >/dev/null
	ninja -C $(BUILD)/ucan-fuzz fuzz_hub_msg
	mkdir -p $(BUILD)/ucan-fuzz/corpus
	$(BUILD)/ucan-fuzz/fuzz_hub_msg -max_total_time=$(FUZZ_SECONDS) -max_len=4200 $(BUILD)/ucan-fuzz/corpus

check: check-ucan check-bus fuzz-ucan
	@echo "make check: all project tests passed"

bench-bus: ucan
	$(PYTHON) ucan/bench/bench_bus.py --build $(UCAN_BUILD)

test:
	@echo "make test: the bench scenarios are not built yet (see README, Status)." >&2
	@exit 1

clean:
	rm -rf $(BUILD)
