# CAN <-> Zenoh bridge test bench. `make help` lists the targets.
SHELL := /bin/bash
.DEFAULT_GOAL := help

BUILD          ?= build
# make check installs the project's Python packages into this virtual environment (never
# the system's); every Python target uses it once it exists.
VENV           ?= .venv
PYTHON         ?= $(if $(wildcard $(VENV)/bin/python),$(CURDIR)/$(VENV)/bin/python,python3)
PYTEST         := $(PYTHON) -m pytest
# Rust and zenohd builds outlive `make clean` and fresh clones: they take minutes.
CACHE          ?= $(HOME)/.cache/canbench
ZENOHD_VERSION := 1.10.2
# the bench's zenohd: the builder image's (its workspace, with the patched zenoh crates of
# docs/upstream/README.md: the hash of what it is built from names the
# build), or ZENOHD=/path/to/zenohd for another
ZENOHD_SOURCES := images/builder/rust firmware/ports/linux/zenoh_rust/Cargo.toml firmware/ports/linux/zenoh_rust/patched scripts/zenohd-source
ZENOHD_PATCHES := $(shell { git ls-files -s $(ZENOHD_SOURCES); git diff HEAD -- $(ZENOHD_SOURCES); \
                   git ls-files -o --exclude-standard $(ZENOHD_SOURCES) | xargs -r sha1sum; } | sha1sum | cut -c1-8)
ZENOHD         ?= $(CACHE)/zenohd-$(ZENOHD_VERSION)-$(ZENOHD_PATCHES)/bin/zenohd
CARGO_TARGET   ?= $(CACHE)/cargo-target
FUZZ_SECONDS   ?= 30
export ZENOHD

UCAN_BUILD     := $(BUILD)/ucan
FW_BUILD       := $(BUILD)/firmware
FW_ASAN_BUILD  := $(BUILD)/firmware-asan
CMAKE_GEN      := -G Ninja
# The ASan bridge runs under the (never sanitized) preload library.
ASAN_ENV       := ASAN_OPTIONS=verify_asan_link_order=0:detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1

# -- the bench in compose --------------------------------------------------------
BASE_IMAGE     ?= debian:bookworm-slim
BENCH_BASE     := canbench/base:bookworm
COMPOSE        ?= $(shell docker compose version >/dev/null 2>&1 && echo "docker compose" || echo docker-compose)
BENCH_CAN_MODE ?= $(shell scripts/detect-can)
BENCH_BUS_CAP  := $(if $(filter kernel,$(BENCH_CAN_MODE)),NET_ADMIN,CHOWN)
IMAGE_SOURCES  := images ucan firmware bench/tools canbench tests/data pyproject.toml .dockerignore scripts/zenohd-source
# content hash of everything the images are built from: unchanged sources, no rebuild.
# Computed once per make run (:=), so the images built and the images tested are the same
# even if a file changes meanwhile.
ifndef BENCH_TAG
BENCH_TAG      := $(shell { git ls-files -s $(IMAGE_SOURCES); git diff HEAD -- $(IMAGE_SOURCES); \
                   git ls-files -o --exclude-standard $(IMAGE_SOURCES) | xargs -r sha1sum; } | sha1sum | cut -c1-12)
endif
SCENARIO       ?= $(wildcard scenarios/*.yaml)
ROUTER_IMAGE   ?= canbench/router:$(BENCH_TAG)
export COMPOSE BENCH_TAG BENCH_CAN_MODE BENCH_BUS_CAP ROUTER_IMAGE BASELINE

# The Zenoh port (Rust over the zenoh crate) is compiled once per cold machine: the host
# build links the port that the builder image compiled from the same Rust sources (.ci/run
# builds the images first), kept in $(CACHE) by the hash of those sources, instead of
# compiling the zenoh crate a second time (25 minutes on a slow 2-core day). Without such an
# image or copy, or with RUST_PORT=cargo, cargo builds it.
RUST_PORT_SOURCES := firmware/ports/linux/zenoh_rust
RUST_PORT_HASH := $(shell { git ls-files -s $(RUST_PORT_SOURCES); git diff HEAD -- $(RUST_PORT_SOURCES); \
                   git ls-files -o --exclude-standard $(RUST_PORT_SOURCES) | xargs -r sha1sum; } | sha1sum | cut -c1-12)
RUST_PORT_DIR  := $(CACHE)/rust-port-$(RUST_PORT_HASH)
ifndef RUST_PORT
RUST_PORT      := $(if $(wildcard $(RUST_PORT_DIR)/libzn_port_zenoh.a),copy,$(if \
                   $(shell docker image inspect canbench/builder:$(BENCH_TAG) >/dev/null 2>&1 && echo y),image,cargo))
endif
ifeq ($(RUST_PORT),cargo)
FW_RUST_ARGS   := -DZN_RUST_PREBUILT_DIR= -DZN_RUST_TARGET_DIR=$(CARGO_TARGET)
FW_RUST_DEP    :=
else
FW_RUST_ARGS   := -DZN_RUST_PREBUILT_DIR=$(RUST_PORT_DIR) -DZN_RUST_TARGET_DIR=$(CARGO_TARGET)
FW_RUST_DEP    := $(RUST_PORT_DIR)/libzn_port_zenoh.a
endif

.PHONY: setup venv summarise scaffold validate open bench help ucan ucan-asan firmware firmware-asan zenohd check check-ucan check-bus check-firmware \
        check-firmware-cross check-port-rust check-python check-bridge check-faults check-compose check-kernel fuzz fuzz-ucan fuzz-hub-proof fuzz-firmware bench-bus bench-bridge bench-capture bench-paths bench-callgrind bench-qos bench-dbc bench-host bench-tools zn-flood test clean preflight base images \
        shell logs soak

help:
	@echo "make test       run the bench's scenarios against the bridge (the main job; SCENARIO=file JOBS=N SHARD=k/n)"
	@echo "make images     build the bench's images (only what changed); make base: the base image"
	@echo "make shell      a shell in the orchestrator image; make logs: the latest run's container logs"
	@echo "make check      the project's own tests (unit, bus conformance, bridge integration, fuzz)"
	@echo "make setup      what make check needs on the host: apt packages if missing, Python packages into $(VENV)/"
	@echo "make summarise TRACE=f | scaffold TRACE=f NAME=n | validate SCENARIO=f | open: canbench (venv or image)"
	@echo "make ucan       build the userspace CAN bus (hub, preload library, ucanctl)"
	@echo "make firmware   build zenoh-node for Linux (C component + Rust Zenoh port)"
	@echo "make zenohd     zenohd $(ZENOHD_VERSION) with the patched zenoh crates, into $(CACHE)"
	@echo "make fuzz       bounded libFuzzer runs (FUZZ_SECONDS=$(FUZZ_SECONDS) each)"
	@echo "make fuzz-hub-proof  the stateful hub fuzzer from an empty corpus on the hub before a fixed defect (FUZZ_PROOF_HUB)"
	@echo "make bench      benchmarks, ratios against baselines measured in the same run (not part of check)"
	@echo "make check-kernel  the real-kernel lane alone (kernel vcan natively, or in QEMU)"
	@echo "make soak       one hour at ~50 % bus load with router restarts (nightly; SOAK_SCENARIO=file)"
	@echo "make clean      remove $(BUILD)/ (not the cache in $(CACHE))"

ucan:
	cmake -S ucan -B $(UCAN_BUILD) $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
	ninja -C $(UCAN_BUILD)

ucan-asan:
	cmake -S ucan -B $(BUILD)/ucan-asan $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=Debug -DUCAN_SANITIZE=ON >/dev/null
	ninja -C $(BUILD)/ucan-asan

firmware: $(FW_RUST_DEP)
	cmake -S firmware -B $(FW_BUILD) $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=RelWithDebInfo $(FW_RUST_ARGS) >/dev/null
	ninja -C $(FW_BUILD)

firmware-asan: $(FW_RUST_DEP)
	cmake -S firmware -B $(FW_ASAN_BUILD) $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=Debug -DZN_SANITIZE=ON $(FW_RUST_ARGS) >/dev/null
	ninja -C $(FW_ASAN_BUILD)

# the builder image's port (same Rust sources: RUST_PORT_HASH is part of BENCH_TAG's input)
$(CACHE)/rust-port-%/libzn_port_zenoh.a:
	@mkdir -p $(CACHE) && tmp=$$(mktemp -d $(CACHE)/rust-port-tmp.XXXXXX) && id=$$(docker create --pull never canbench/builder:$(BENCH_TAG)) && \
	 docker cp $$id:/build/rust/release/libzn_port_zenoh.a $$tmp/ && docker cp $$id:/build/rust/release/zn-capture $$tmp/; \
	 rc=$$?; docker rm $$id >/dev/null; [ $$rc = 0 ] && chmod 755 $$tmp && rm -rf $(@D) && mv $$tmp $(@D) || { rm -rf $$tmp; exit 1; }
	@echo "Zenoh port: copied from canbench/builder:$(BENCH_TAG) into $(@D)"

# zenohd is compiled once per cold machine: taken from the builder image when
# Docker works (the images need it anyway), else built by the host's cargo as the image does.
$(CACHE)/zenohd-$(ZENOHD_VERSION)-$(ZENOHD_PATCHES)/bin/zenohd:
	@if docker info >/dev/null 2>&1; then \
	   $(MAKE) --no-print-directory images && mkdir -p $(@D) && \
	   id=$$(docker create --pull never canbench/builder:$(BENCH_TAG)) && docker cp $$id:/opt/zenohd/bin/zenohd $@ && \
	   docker rm $$id >/dev/null && echo "zenohd: copied from canbench/builder:$(BENCH_TAG)"; \
	 else \
	   CARGO_TARGET_DIR=$(CARGO_TARGET)/zenohd scripts/build-zenohd $(ZENOHD_VERSION) $@; \
	 fi

zenohd: $(ZENOHD)
	@$(ZENOHD) --version

check-ucan: ucan ucan-asan
	ctest --test-dir $(UCAN_BUILD) --output-on-failure
	ctest --test-dir $(BUILD)/ucan-asan --output-on-failure

# The conformance suite against the release hub, then against the ASan/UBSan hub
# (the preload library is never sanitized: it lives inside arbitrary programs).
check-bus: ucan ucan-asan
	UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) $(PYTEST) -q -rs tests/bus --ignore tests/bus/test_differential.py
	UCAN_BUILD=$(CURDIR)/$(BUILD)/ucan-asan $(PYTEST) -q tests/bus --ignore tests/bus/test_differential.py

# The component's unit tests on mock ports (release and ASan/UBSan): no Zenoh port needed.
FW_UNIT_BUILD  := $(BUILD)/firmware-unit
# The component cross-compiled for the target's kind of core (firmware/cross: rv32imc,
# picolibc; -Werror, per-function stack budget from Kconfig). Compiles only: a few seconds.
check-firmware-cross:
	cmake -S firmware/cross -B $(BUILD)/firmware-cross $(CMAKE_GEN) \
	  -DCMAKE_TOOLCHAIN_FILE=$(CURDIR)/firmware/cross/rv32imc-picolibc.cmake >/dev/null
	ninja -C $(BUILD)/firmware-cross

check-firmware: check-firmware-cross
	cmake -S firmware -B $(FW_UNIT_BUILD) $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DZN_BUILD_BRIDGE=OFF >/dev/null
	ninja -C $(FW_UNIT_BUILD)
	ctest --test-dir $(FW_UNIT_BUILD) --output-on-failure
	cmake -S firmware -B $(FW_UNIT_BUILD)-asan $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=Debug -DZN_SANITIZE=ON -DZN_BUILD_BRIDGE=OFF >/dev/null
	ninja -C $(FW_UNIT_BUILD)-asan
	$(ASAN_ENV) ctest --test-dir $(FW_UNIT_BUILD)-asan --output-on-failure

# The Zenoh port's Rust unit tests (firmware/ports/linux/zenoh_rust/src/lib.rs), in the builder
# image with its sources and lock. Not part of check: a test build ignores the release profile's
# panic = "abort", so zenoh and its dependencies compile once more (about 7 minutes on 2 cores).
check-port-rust: images
	docker run --rm --network none -v $(CURDIR)/firmware/ports/linux/zenoh_rust:/mnt/port:ro \
	  -v $(CURDIR)/images/builder/rust/Cargo.lock:/mnt/Cargo.lock:ro canbench/builder:$(BENCH_TAG) sh -c \
	  'cp -r /mnt/port/. /src/rust/zn_port_zenoh/ && cp /mnt/Cargo.lock /src/rust/Cargo.lock && \
	   CARGO_TARGET_DIR=/build/rust cargo test -q --release --locked --offline --workspace --no-default-features --lib \
	   --manifest-path /src/rust/Cargo.toml'

check-python:
	$(PYTHON) -m ruff check canbench tests bench
	$(PYTHON) -m mypy --ignore-missing-imports canbench
	$(PYTEST) -q -m unit tests/unit

# The bridge with zenohd on the host bus: release build, then ASan/UBSan build.
check-bridge: ucan firmware firmware-asan zenohd
	ZN_CAPTURE=$(CURDIR)/$(FW_BUILD)/zn-capture UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) ZN_BRIDGE=$(CURDIR)/$(FW_BUILD)/zenoh-node $(PYTEST) -q tests/bridge
	$(ASAN_ENV) UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) ZN_BRIDGE=$(CURDIR)/$(FW_ASAN_BUILD)/zenoh-node $(PYTEST) -q tests/bridge

# The hub's message validator, then the hub's state (sequences over many connections, in process).
fuzz-ucan:
	cmake -S ucan -B $(BUILD)/ucan-fuzz $(CMAKE_GEN) -DCMAKE_C_COMPILER=clang -DUCAN_FUZZ=ON >/dev/null
	ninja -C $(BUILD)/ucan-fuzz fuzz_hub_msg fuzz_hub_state
	mkdir -p $(BUILD)/ucan-fuzz/corpus $(BUILD)/ucan-fuzz/corpus-state
	$(BUILD)/ucan-fuzz/fuzz_hub_msg -max_total_time=$(FUZZ_SECONDS) -max_len=4200 $(BUILD)/ucan-fuzz/corpus
	$(BUILD)/ucan-fuzz/fuzz_hub_state -max_total_time=$(FUZZ_SECONDS) -max_len=256 -rss_limit_mb=1024 \
	  $(BUILD)/ucan-fuzz/corpus-state ucan/fuzz/seeds/hub_state

# The stateful fuzzer's proof: from an empty corpus, on the hub before issue 19's defect 1 was
# fixed (FUZZ_PROOF_HUB = 7900d7c^, its sources from git), it must report the flush-list overflow.
# (Leak checks off: that hub also leaks a reply queue under nested BARRIERs, defect 4, found too.)
FUZZ_PROOF_HUB     ?= 338c49b
FUZZ_PROOF_SECONDS ?= 600
fuzz-hub-proof:
	rm -rf $(BUILD)/fuzz-proof && mkdir -p $(BUILD)/fuzz-proof/corpus
	git archive $(FUZZ_PROOF_HUB) ucan/src ucan/include | tar -x -C $(BUILD)/fuzz-proof
	clang -g -O1 -fsanitize=fuzzer,address -DFUZZ_HUB_NO_INVARIANTS -Wno-gnu-variable-sized-type-not-at-end \
	  -I$(BUILD)/fuzz-proof/ucan/include -I$(BUILD)/fuzz-proof/ucan/src ucan/fuzz/fuzz_hub_state.c \
	  $(addprefix $(BUILD)/fuzz-proof/ucan/src/,hub.c canframelen.c canfilter.c ucan_msg.c) -o $(BUILD)/fuzz-proof/fuzz_hub_state
	-nice -n 10 $(BUILD)/fuzz-proof/fuzz_hub_state -max_total_time=$(FUZZ_PROOF_SECONDS) -max_len=256 -rss_limit_mb=1024 -detect_leaks=0 \
	  -artifact_prefix=$(BUILD)/fuzz-proof/ $(BUILD)/fuzz-proof/corpus > $(BUILD)/fuzz-proof/log 2>&1
	grep -m1 "SUMMARY: AddressSanitizer: heap-buffer-overflow .* in client_send" $(BUILD)/fuzz-proof/log
	grep -o "^#[0-9]*" $(BUILD)/fuzz-proof/log | tail -1 | sed 's/^#/inputs run: /'

fuzz-firmware:
	cmake -S firmware -B $(BUILD)/firmware-fuzz $(CMAKE_GEN) -DCMAKE_C_COMPILER=clang -DZN_FUZZ=ON -DZN_BUILD_BRIDGE=OFF >/dev/null
	ninja -C $(BUILD)/firmware-fuzz fuzz_decode
	mkdir -p $(BUILD)/firmware-fuzz/corpus
	$(BUILD)/firmware-fuzz/fuzz_decode -max_total_time=$(FUZZ_SECONDS) -max_len=1100 $(BUILD)/firmware-fuzz/corpus

fuzz: fuzz-ucan fuzz-firmware

# Real-kernel lane: the conformance suite and the differential check (userspace hub vs
# kernel vcan, same frames) on kernel vcan - natively where the kernel has vcan, else
# in Debian's kernel under QEMU (ucan/vm/vcan-vm), where the bridge's CAN port runs too.
KERNEL_LANE_BRIDGE_TESTS := every_frame_kind or invalid_commands or sigterm
# Under QEMU the emulated ECU's own timing (test_ecu_lateness) is the emulation's, not the bench's:
# that test runs in check-bus on the host only.
# Under emulation every process start counts: the interpreter itself, not a version-manager
# shim (pyenv's is a bash script), and no entry-point scan for pytest plugins (the lane needs none; canbench's is for bench runs).
VM_PYTHON = $(shell $(PYTHON) -c 'import sys; print(sys.executable)')
check-kernel: ucan firmware zenohd
	@if [ "$$(BENCH_CAN=auto scripts/detect-can)" = kernel ]; then \
	   echo "kernel lane: native kernel vcan"; \
	   UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) BENCH_CAN=kernel $(PYTEST) -q tests/bus tests/bridge/test_bridge_host.py -k "$(KERNEL_LANE_BRIDGE_TESTS) or not bridge"; \
	 else \
	   echo "kernel lane: Debian's kernel in QEMU (ucan/vm/vcan-vm), no kernel vcan on this host"; \
	   ucan/vm/vcan-vm -- env UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) ZENOHD=$(ZENOHD) ZN_BRIDGE=$(CURDIR)/$(FW_BUILD)/zenoh-node \
	     PYTEST_DISABLE_PLUGIN_AUTOLOAD=1 $(VM_PYTHON) -m pytest -p no:cacheprovider -q tests/bus tests/bridge/test_bridge_host.py -k "$(KERNEL_LANE_BRIDGE_TESTS) or not bridge" --ignore=tests/bus/test_ecu_lateness.py; \
	 fi

# The bench must catch a broken bridge: each seeded fault fails exactly its checks.
check-faults: ucan firmware zenohd
	ZN_CAPTURE=$(CURDIR)/$(FW_BUILD)/zn-capture UCAN_BUILD=$(CURDIR)/$(UCAN_BUILD) ZN_BRIDGE=$(CURDIR)/$(FW_BUILD)/zenoh-node $(PYTEST) -q tests/faults

# The bench itself in compose, as make test runs it.
check-compose: images ucan firmware
	BENCH_REQUIRE_IMAGES=1 $(PYTEST) -q tests/compose

# make check's phases, in order (scripts/run-phases: progress and each phase's time)
CHECK_PHASES := check-python check-ucan check-firmware check-bus check-kernel check-bridge check-faults fuzz check-compose
check: setup
	@MAKE="$(MAKE)" scripts/run-phases check $(CHECK_PHASES)
	@echo "make check: all project tests passed"

# -- host set-up: make check installs what it needs (scripts/host-deps: apt-get as root or with
# passwordless sudo, else it names the command), Python packages into $(VENV)/ --------------
HOST_APT_CHECK := gcc libc6-dev python3 python3-venv can-utils cmake ninja-build clang libclang-rt-14-dev \
                  iproute2 util-linux qemu-system-x86 busybox-static cpio kmod gdb \
                  gcc-riscv64-unknown-elf picolibc-riscv64-unknown-elf
setup:
	@scripts/host-deps "make check" $(HOST_APT_CHECK)
	@$(MAKE) --no-print-directory venv

# the venv is (re)made when pyproject.toml changes; a half-made one is removed
venv: $(VENV)/.installed
$(VENV)/.installed: pyproject.toml
	@echo "setup: Python packages into $(VENV)/ (pip install -e '.[test,viewer]')"
	@rm -rf $(VENV) && python3 -m venv $(VENV) && \
	 $(VENV)/bin/pip install -q --disable-pip-version-check -e '.[test,viewer]' || { rm -rf $(VENV); exit 1; }
	@touch $@
	@echo "setup: $(VENV)/bin/canbench ready (or: source $(VENV)/bin/activate)"

# canbench for scenario writing, right after make test or make check: from $(VENV)/ when it
# exists, else in the orchestrator image with this checkout mounted at its own path.
CANBENCH = $(if $(wildcard $(VENV)/bin/canbench),$(VENV)/bin/canbench,docker run --rm --pull never --network none -u $$(id -u):$$(id -g) \
           -v $(CURDIR):$(CURDIR) -w $(CURDIR) canbench/orchestrator:$(BENCH_TAG) canbench)
CANBENCH_DEP = $(if $(wildcard $(VENV)/bin/canbench),,images)
# Paths are quoted for the shell ('a b.log', it's.log); a TRACE or SCENARIO naming one file is one
# argument, spaces and all, else a list of them (summarise and validate take several).
summarise: $(CANBENCH_DEP)
	@paths='$(subst ','\'',$(TRACE))'; if [ -e "$$paths" ]; then set -- "$$paths"; else set -- $$paths; fi; \
	 $(CANBENCH) summarise "$$@" $(if $(DBC),--dbc '$(subst ','\'',$(DBC))')
scaffold: $(CANBENCH_DEP)
	@$(CANBENCH) scaffold $(if $(TRACE),'$(subst ','\'',$(TRACE))') $(if $(NAME),--name '$(subst ','\'',$(NAME))') \
	 $(if $(DBC),--dbc '$(subst ','\'',$(DBC))')
validate: $(CANBENCH_DEP)
	@paths='$(subst ','\'',$(SCENARIO))'; if [ -e "$$paths" ]; then set -- "$$paths"; else set -- $$paths; fi; \
	 $(CANBENCH) validate "$$@"
open:
	@test -f reports/latest/report.html || { echo "open: no reports/latest/report.html (make test writes it)" >&2; exit 1; }
	@echo "$(CURDIR)/reports/latest/report.html"
	@if command -v xdg-open >/dev/null && [ -n "$${DISPLAY:-}$${WAYLAND_DISPLAY:-}" ]; then xdg-open reports/latest/report.html; fi

# The benchmarks' loads (bench/tools): can-load, the stamped CAN load, echo ECU and counting
# reader; hop_latency, one hop of a bus; zn-flood, a paced Rust publisher (same zenoh and
# target dir as the port, so only its own crate compiles).
BENCH_TOOLS_BUILD := $(BUILD)/bench-tools
CAN_LOAD := $(BENCH_TOOLS_BUILD)/can-load
ZN_FLOOD := $(CARGO_TARGET)/release/zn-flood
bench-tools:
	cmake -S bench/tools -B $(BENCH_TOOLS_BUILD) $(CMAKE_GEN) -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
	ninja -C $(BENCH_TOOLS_BUILD)

zn-flood:
	CARGO_TARGET_DIR=$(CARGO_TARGET) cargo build --release --manifest-path bench/tools/zn-flood/Cargo.toml

bench-bus: ucan bench-tools
	$(PYTHON) -m bench.bus --build $(UCAN_BUILD) --tools $(BENCH_TOOLS_BUILD) --out $(BENCH_OUT)

# zenoh-node against the Python reference bridge both ways, same run, same bus/router/capture
# (README's performance table is generated from it: BENCH_README=1).
bench-bridge: ucan firmware zenohd bench-tools zn-flood
	ZENOHD=$(ZENOHD) $(PYTHON) -m bench.bridge $(BENCH_TOOLS) $(if $(BENCH_README),--update-readme)

# The bench's captures at >= 100k frames/s: zn-flood into zn-capture; cangen into candump -L.
bench-capture: ucan firmware zenohd zn-flood
	ZENOHD=$(ZENOHD) $(PYTHON) -m bench.capture --zn-flood $(ZN_FLOOD) --zn-capture $(FW_BUILD)/zn-capture --out $(BENCH_OUT)

# Latency and throughput of every path through the bridge next to the bus alone, raw Zenoh and
# the Python reference; instructions per frame under callgrind (BENCH_RECORD=1 appends them to
# docs/callgrind-history.csv).
# One output directory per make run: all benchmarks of `make bench` write side by side.
BENCH_OUT := reports/bench/$(shell date -u +%Y%m%d-%H%M%S)
BENCH_TOOLS = --zn-flood $(ZN_FLOOD) --can-load $(CAN_LOAD) --zn-capture $(FW_BUILD)/zn-capture --out $(BENCH_OUT)
bench-paths: ucan firmware zenohd bench-tools zn-flood
	ZENOHD=$(ZENOHD) $(PYTHON) -m bench.paths $(BENCH_TOOLS) $(if $(BENCH_QUICK),--quick)

bench-callgrind: ucan firmware zenohd bench-tools zn-flood
	ZENOHD=$(ZENOHD) $(PYTHON) -m bench.callgrind $(BENCH_TOOLS) $(if $(BENCH_RECORD),--record)

# What the CAN -> Zenoh QoS table (--rx-qos) buys: a high-priority id's latency under a flood with
# and without it, loss per reliability and congestion control while zenohd is stopped
# (BENCH_QUICK=1: a smoke run).
bench-qos: ucan firmware zenohd bench-tools
	ZENOHD=$(ZENOHD) $(PYTHON) -m bench.qos $(BENCH_TOOLS) $(if $(BENCH_QUICK),--quick)

# Benchmarks for nightly runs, never part of check (docs/benchmark.md, docs/userspace-bus.md):
# in compose, with the binaries of the images `make test` runs (compose.bench.yaml, no network);
# BENCHMARKS= picks some of them. bench-host runs the same scripts with the host's builds.
BENCHMARKS ?= bus bridge capture paths callgrind qos viewer dbc
bench: images
	@scripts/build-images $(BENCH_TAG) $(BENCH_BASE) bench
	@mkdir -p $(BENCH_OUT)
	BENCH_UID=$$(id -u) BENCH_GID=$$(id -g) BENCH_COMMIT=$$(git rev-parse --short HEAD) $(COMPOSE) -f compose.bench.yaml -p canbench-bench run --rm \
	  bench run-bench /repo/$(BENCH_OUT) $(BENCHMARKS)
	@echo "make bench: results in $(BENCH_OUT)"

# canbench view into an .rrd at 50 000 CAN frames/s + a 640x480 image at 10 Hz (docs/viewer.md)
bench-viewer:
	$(PYTHON) -m bench.viewer --out $(BENCH_OUT)

# DBC load and signal-decode time: cantools' large DBCs and a generated one (bench/dbc.py)
bench-dbc:
	$(PYTHON) -m bench.dbc --out $(BENCH_OUT)

bench-host: bench-bus bench-bridge bench-capture bench-paths bench-callgrind bench-qos bench-viewer bench-dbc

preflight:
	@command -v docker >/dev/null || { echo "preflight: docker is not installed (https://docs.docker.com/engine/install/)" >&2; exit 1; }
	@docker info >/dev/null 2>&1 || { echo "preflight: the Docker daemon is not running or not reachable (sudo systemctl start docker; are you in the docker group?)" >&2; exit 1; }
	@$(COMPOSE) version >/dev/null 2>&1 || { echo "preflight: neither 'docker compose' nor docker-compose works (apt-get install docker-compose)" >&2; exit 1; }
	@echo "preflight: compose: $(COMPOSE); CAN bus: $(BENCH_CAN_MODE)$(if $(filter kernel,$(BENCH_CAN_MODE)), (kernel vcan, bus gets NET_ADMIN), (userspace hub)); images: canbench/*:$(BENCH_TAG)"

base: preflight
	@BUILD_DIR=$(BUILD) images/base/make-base.sh $(BASE_IMAGE) $(BENCH_BASE)

images: base
	@scripts/build-images $(BENCH_TAG) $(BENCH_BASE)

# every scenario validated first (exit 2, nothing started), then run JOBS at a time, each in
# its own compose project; SHARD=k/n: this runner's share; one summary in reports/<suite>/
JOBS  ?= 1
SHARD ?=
# DEVICE=host:PORT [DEVICE_CMD=... | DEVICE_HOOK=...] [DEVICE_ANNOUNCES=0]: a device of your own in the bridge's place
# (scripts/bench-run; DEVICE_ANNOUNCES=0 for one with no liveliness token and no stats queryable);
# a host process joins the userspace bus through the host's build of the preload library
test: images $(if $(DEVICE),ucan)
	@JOBS=$(JOBS) SHARD=$(SHARD) scripts/bench-suite $(SCENARIO)

# Nightly soak: one hour, memory slope and descriptor growth gated (docs/faults.md).
SOAK_SCENARIO ?= scenarios/nightly/soak.yaml
soak: images
	@scripts/bench-run $(SOAK_SCENARIO)

shell: images
	docker run --rm -it --pull never --network none -v $(CURDIR)/scenarios:/scenarios:ro -v $(CURDIR)/reports:/reports canbench/orchestrator:$(BENCH_TAG) bash

logs:
	@cat reports/latest/containers.log

clean:
	rm -rf $(BUILD)
