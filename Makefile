# jakagw - JAKA robot to Modbus TCP gateway, and jakasim, its robot simulator.
#
#   make            build build/jakagw and build/jakasim
#   make demo       install missing packages, build, run the gateway on the simulator
#   make test       install missing packages, build, run every test (plain and ASan/UBSan)
#   make test-plc   the PLC library (plc/) compiled with matiec and run as a PLC (docs/plc-library.md)
#   make prove      prove the Modbus request check and the RTU CRC and length functions (Frama-C WP)
#   make install    install into $(DESTDIR)$(PREFIX) (binaries, config, units, man pages, docs)
#   make deb        build the Debian package into $(BUILD)/deb/
#   make ARCH=arm64 (or armhf), make deb ARCH=..., make test ARCH=...
#                   the same for an ARM board, in build-ARCH/ (docs/arm.md)

VERSION   := 0.1.0
PREFIX    ?= /usr/local
BINDIR    ?= $(PREFIX)/bin
SBINDIR   ?= $(PREFIX)/sbin
SYSCONFDIR ?= /etc
DOCDIR    ?= $(PREFIX)/share/doc/jakagw
MANDIR    ?= $(PREFIX)/share/man
# Debian 12's systemd keeps the units of /usr in /lib/systemd/system; any
# other prefix keeps them under itself (/usr/local/lib/systemd/system is on
# systemd's search path too).
UNITDIR   ?= $(if $(filter /usr,$(PREFIX)),/lib/systemd/system,$(PREFIX)/lib/systemd/system)
# The generator that gives the units the serial port of [rtu] device
# (systemd/jakagw-generator.in), beside the units' directory.
GENERATORDIR ?= $(patsubst %/system,%/system-generators,$(UNITDIR))
# The units' start condition (systemd/jakagw-condition.in).
LIBEXECDIR ?= $(PREFIX)/libexec/jakagw
DESTDIR   ?=

# Cross builds for ARM boards (docs/arm.md): make ARCH=arm64 or
# make ARCH=armhf builds into build-ARCH/ with Debian's cross compiler,
# against a sysroot of Debian 12's packages for that architecture
# (build-ARCH/sysroot/), which scripts/make-sysroot.sh makes when it is
# missing or its package list changed. make test ARCH=... runs the tests
# with the binaries under qemu-user. Only ARCH given on the command line
# counts: an ARCH in the environment (a kernel build's) changes nothing.
ifeq ($(origin ARCH),command line)
CROSS_TRIPLET_arm64 := aarch64-linux-gnu
CROSS_TRIPLET_armhf := arm-linux-gnueabihf
CROSS_QEMU_arm64 := qemu-aarch64
CROSS_QEMU_armhf := qemu-arm
TRIPLET   := $(CROSS_TRIPLET_$(ARCH))
ifeq ($(TRIPLET),)
$(error ARCH=$(ARCH): the architectures are arm64 and armhf (no ARCH: this machine's))
endif
BUILD     ?= build-$(ARCH)
SYSROOT   ?= $(abspath $(BUILD))/sysroot
ifeq ($(origin CC),default)
CC        := $(TRIPLET)-gcc
endif
ifeq ($(origin AR),default)
AR        := $(TRIPLET)-ar
endif
ARCH_CFLAGS := --sysroot=$(SYSROOT)
# override: a package build's dh_auto_build passes PKG_CONFIG=TRIPLET-pkg-config,
# which would look in this machine's multiarch directories, not the sysroot.
override PKG_CONFIG := PKG_CONFIG_SYSROOT_DIR=$(SYSROOT) \
    PKG_CONFIG_LIBDIR=$(SYSROOT)/usr/lib/$(TRIPLET)/pkgconfig:$(SYSROOT)/usr/share/pkgconfig pkg-config
# The command line the tests put before each binary (tests/run.sh).
JAKAGW_RUNNER := $(CROSS_QEMU_$(ARCH)) -L $(SYSROOT)
export JAKAGW_RUNNER
# Goals that compile need the sysroot before pkg-config is asked.
ifneq ($(filter-out deps demo test clean uninstall deb test-package test-service,$(or $(MAKECMDGOALS),all)),)
ifneq ($(shell scripts/make-sysroot.sh $(ARCH) $(SYSROOT) >&2 || echo failed),)
$(error could not make the $(ARCH) sysroot $(SYSROOT))
endif
endif
endif
PKG_CONFIG ?= pkg-config
BUILD     ?= build
CC        ?= cc
SAMPLES_DIR ?= $(abspath tests/data)

PKGS      := libuv libmodbus libcjson inih libsystemd openssl libmicrohttpd
# deps, demo, test and clean work on a bare machine (demo and test install
# the packages first); any other goal needs the compiler and the .pc files,
# and says how to get them instead of failing with compiler errors.
NO_PKG_GOALS := deps demo test clean uninstall deb test-package test-service
ifneq ($(filter-out $(NO_PKG_GOALS),$(or $(MAKECMDGOALS),all)),)
MISSING_PKGS := $(shell command -v $(CC) >/dev/null || echo $(CC); \
    for p in $(PKGS) $(if $(filter unit-tests san valgrind,$(MAKECMDGOALS)),cmocka); do \
        $(PKG_CONFIG) --exists $$p 2>/dev/null || echo $$p; done)
ifneq ($(MISSING_PKGS),)
$(error missing $(strip $(MISSING_PKGS)): run 'make deps' first (or make demo / make test))
endif
endif
PKG_CFLAGS := $(shell $(PKG_CONFIG) --cflags $(PKGS) 2>/dev/null)
PKG_LIBS   := $(shell $(PKG_CONFIG) --libs $(PKGS) 2>/dev/null)
TEST_LIBS  := $(shell $(PKG_CONFIG) --libs cmocka 2>/dev/null)

WARN      := -Wall -Wextra -Werror -Wshadow -Wstrict-prototypes -Wmissing-prototypes -Wformat=2
CFLAGS    ?= -O2 -g
# src/ is one folder per layer or subsystem, each header beside its source
# (docs/architecture.md); every folder is on the include path, and
# tests/integration/test_layout.py checks that includes only point down.
# A unit test may #include the .c under test from any of them.
SRC_DIRS  := $(sort $(dir $(wildcard src/*/*.c)))
INC_FLAGS := $(SRC_DIRS:%=-I%) $(if $(wildcard include/*.h),-Iinclude)
ALL_CFLAGS := -std=c11 -D_DEFAULT_SOURCE -DJAKAGW_VERSION='"$(VERSION)"' \
              $(WARN) $(CPPFLAGS) $(CFLAGS) $(EXTRA_CFLAGS) $(ARCH_CFLAGS) $(INC_FLAGS) $(PKG_CFLAGS) -MMD -MP
ALL_LDFLAGS := $(LDFLAGS) $(EXTRA_LDFLAGS)

MAIN_SRC  := $(wildcard src/*/main.c)
LIB_SRCS  := $(filter-out $(MAIN_SRC),$(wildcard src/*/*.c))
SIM_SRCS  := $(wildcard sim/*.c)
UNIT_TESTS := $(patsubst tests/%.c,%,$(wildcard tests/test_*.c))

LIB_OBJS  := $(LIB_SRCS:%.c=$(BUILD)/%.o) $(BUILD)/gen/status_page.o
SIM_OBJS  := $(SIM_SRCS:%.c=$(BUILD)/%.o)

.PHONY: screenshot bench-http bench-http-registers all deps demo test soak test-netem unit-tests check-docs docs man install uninstall deb test-package test-service clean san valgrind bench fuzz fuzz-check fuzz-ci test-can test-load
all: $(BUILD)/jakagw $(BUILD)/jakasim

$(BUILD)/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) -c $< -o $@

# The status page (www/status.html) as a C array in the binary.
$(BUILD)/gen/status_page.c: www/status.html scripts/embed.sh
	@mkdir -p $(dir $@)
	scripts/embed.sh status_page_html $< > $@.tmp && mv $@.tmp $@

$(BUILD)/gen/status_page.o: $(BUILD)/gen/status_page.c
	$(CC) $(ALL_CFLAGS) -c $< -o $@

$(BUILD)/libjakagw.a: $(LIB_OBJS)
	$(AR) rcs $@ $^

$(BUILD)/jakagw: $(MAIN_SRC:%.c=$(BUILD)/%.o) $(BUILD)/libjakagw.a
	$(CC) $(ALL_CFLAGS) $^ -o $@ $(ALL_LDFLAGS) $(PKG_LIBS) -lm

$(BUILD)/jakasim: $(SIM_OBJS) $(BUILD)/libjakagw.a
	$(CC) $(ALL_CFLAGS) $^ -o $@ $(ALL_LDFLAGS) $(PKG_LIBS) -lm

# A unit test may #include the .c under test to reach its static helpers.
$(BUILD)/tests/%: tests/%.c $(BUILD)/libjakagw.a
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) -DSAMPLES_DIR="\"$(SAMPLES_DIR)\"" -DCONFIG_FILE="\"$(abspath config/jakagw.conf)\"" $< $(BUILD)/libjakagw.a -o $@ $(ALL_LDFLAGS) $(PKG_LIBS) $(TEST_LIBS) -lm

unit-tests: $(UNIT_TESTS:%=$(BUILD)/tests/%)

# The PLC of the netem VM test (tests/can/test_netem_vm.py), which has no
# Python: a libmodbus master with a heartbeat thread.
$(BUILD)/tests/netem_plc: tests/can/netem_plc.c
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) $< -o $@ $(ALL_LDFLAGS) $(PKG_LIBS) -lpthread

$(BUILD)/bench/%: bench/%.c $(BUILD)/libjakagw.a
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) $< $(BUILD)/libjakagw.a -o $@ $(ALL_LDFLAGS) $(PKG_LIBS) -lm

# The reference slave of the abuse test: plain libmodbus, no libjakagw.
$(BUILD)/bench/ref_slave: bench/ref_slave.c
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) $< -o $@ $(ALL_LDFLAGS) $(PKG_LIBS)

# The floor bench_forward measures jakagw against: an epoll loop, no library.
$(BUILD)/bench/floor_forwarder: bench/floor_forwarder.c
	@mkdir -p $(dir $@)
	$(CC) $(ALL_CFLAGS) $< -o $@ $(ALL_LDFLAGS)

# Prints costs as ratios to references measured in the same run: a status
# document's whole ingest path against cJSON's parse and delete of it, in
# instructions counted by callgrind (valgrind, from make deps) and in time,
# with the ten functions that cost the most; a command from a Modbus write
# to the robot's socket through the whole gateway, and beside a floor
# forwarder of its own at idle, paced with and without /metrics scraped at
# 10 Hz, with 1 kHz status and after a backlog of 50 documents, with system
# calls and instructions per command, and the status's age at the PLC (a
# document sent to the first FC04 that shows it) (bench_forward, about 3
# minutes); Modbus reads through jakagw (jakasim streaming at 125 Hz) against a plain libmodbus slave, with
# server CPU, the stream's cost and memory. About 5 minutes: the memory
# figure feeds a million documents (BENCH_MODBUS_FLAGS="--documents N" for
# fewer). Then Modbus/TCP Security against plain Modbus TCP in one jakagw:
# CPU per request, handshakes, memory per TLS connection. Last, Modbus RTU
# over socat ptys at 115200 baud against a bare libmodbus RTU slave, and
# Modbus TCP alone and with an RTU master polling (bench_rtu, socat).
bench: all $(BUILD)/bench/bench_pipeline $(BUILD)/bench/bench_commands \
       $(BUILD)/bench/bench_modbus $(BUILD)/bench/ref_slave $(BUILD)/bench/bench_tls \
       $(BUILD)/bench/bench_rtu $(BUILD)/bench/bench_forward $(BUILD)/bench/floor_forwarder
	@$(BUILD)/bench/bench_pipeline tests/data/status-controller-a.json
	@$(BUILD)/bench/bench_commands
	@$(BUILD)/bench/bench_forward
	@$(BUILD)/bench/bench_modbus --document tests/data/status-controller-a.json $(BENCH_MODBUS_FLAGS)
	@$(BUILD)/bench/bench_tls
	@$(BUILD)/bench/bench_rtu

# What the HTTP side costs Modbus: the 32-client load with /metrics scraped
# at 10 Hz and the status page open in headless Chromium, against the same
# load without HTTP clients (Modbus p50/p99 and their ratio), and the
# gateway's CPU per scrape (bench/bench_http.py, about 2 minutes).
bench-http: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 bench/bench_http.py

# The review's load of issue 30: 16 local processes fetching
# /status.json?registers=1 back to back during the 32-client Modbus load;
# Modbus p99 against the same load without them, and the fetches' median
# (bench/bench_http_registers.py, about 40 s).
bench-http-registers: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 bench/bench_http_registers.py

# Installs the Debian packages the build and the tests need, if missing,
# saying which and why. DEPS_GROUPS="build tests ..." picks groups
# (scripts/install-deps.sh --list shows them).
deps:
	@scripts/install-deps.sh $(DEPS_GROUPS)

# The builds that make test, make san, make demo and the fuzz targets start
# compile on every processor (JOBS=1 for one at a time).
JOBS ?= $(shell nproc 2>/dev/null || echo 1)

# The sanitizer build: the same sources in build-san/ with ASan and UBSan.
SAN_FLAGS := -O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all
san:
	$(MAKE) -j$(JOBS) BUILD=build-san CFLAGS="$(SAN_FLAGS)" EXTRA_LDFLAGS="-fsanitize=address,undefined" all unit-tests

# The builds run in a sub-make: pkg-config's flags are read when a make
# starts, and on a fresh machine the packages arrive only with 'deps'.
# The demo needs only what builds it; make test installs the rest.
demo:
	@scripts/install-deps.sh build
	$(MAKE) -j$(JOBS) all
	@scripts/demo.sh

test: deps
ifeq ($(TRIPLET),)
	$(MAKE) -j$(JOBS) all unit-tests $(BUILD)/bench/ref_slave
	$(MAKE) san
	@tests/run.sh
	@if [ "$$CI" = true ] && [ "$(CI_FUZZ_SECONDS)" != 0 ]; then $(MAKE) fuzz-ci FUZZ_SECONDS=$(CI_FUZZ_SECONDS); fi
else
# ARM: the same unit and integration tests, the binaries under qemu-user
# (JAKAGW_RUNNER), then the package. The sanitizers and the fuzzers run on
# this machine's build (qemu-user cannot host ASan's shadow memory).
# SUITES="status_map commands" picks integration suites (tests/run.sh).
	$(MAKE) -j$(JOBS) all unit-tests $(BUILD)/bench/ref_slave
	@BUILDS=$(BUILD) JAKAGW_ARCH=$(ARCH) tests/run.sh
endif

# Frama-C's WP proves src/modbus/mb_request.c and rtu_frame.c's CRC and
# length functions free of runtime errors and true to their ACSL contracts
# (with z3 and cvc4 through why3; the group prove of make deps), prints
# "N of N goals proved" per file, fails on any goal not proved, and checks
# that a copy with one bound removed fails (scripts/prove.sh,
# docs/tests.md). PROVE_TIMEOUT: seconds per goal (default 30).
.PHONY: prove
prove:
	@scripts/prove.sh $(BUILD) "$(INC_FLAGS) $(PKG_CFLAGS) -D_DEFAULT_SOURCE"

# The PLC library (plc/) run as a PLC: builds matiec from its source
# tarball outside this tree (MATIEC_TARBALL, default
# ../shared/tools/matiec/matiec-*.tar.gz; cached in $(BUILD)/matiec-HASH),
# compiles every .st file of plc/ with iec2c, runs the blocks' unit tests
# and the end-to-end cases against jakagw and jakasim (tests/plc/test_plc.py,
# docs/plc-library.md). make test runs it too (tests/run.sh).
.PHONY: test-plc
test-plc: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 tests/plc/test_plc.py

# 32 Modbus clients at 1000 requests/s in total for LOAD_SECONDS, with
# commands, the heartbeat and the status at 125 Hz; make test runs it too
# (tests/run.sh runs every integration test).
LOAD_SECONDS ?= 60
test-load: all
	JAKAGW_BIN_DIR=$(BUILD) LOAD_SECONDS=$(LOAD_SECONDS) /usr/bin/python3 tests/integration/test_load.py

# The chaos soak (not part of make test): jakasim, the sanitizer build of
# jakagw and a PLC running the command recipe in a loop for SOAK_S seconds,
# under a random schedule of silent pulls, RSTs and random loss on every
# link, in a private network namespace with nftables (needs root).
# SOAK_SEED=N repeats a schedule. Prints faults, commands, violations (0
# passes) and detection times per fault kind (docs/tests.md, "The chaos soak").
SOAK_S ?= 600
soak:
	$(MAKE) BUILD=build-san CFLAGS="$(SAN_FLAGS)" EXTRA_LDFLAGS="-fsanitize=address,undefined" all
	JAKAGW_BIN_DIR=build-san SOAK_S=$(SOAK_S) /usr/bin/python3 tests/soak/soak.py

# docs/status-page.png and docs/status-page-fault.png: the status page of a
# running demo, as headless Chromium shows it on a 390 px phone, and with
# fault 1 latched (scripts/screenshot.py; make deps installs chromium,
# chromium-driver and python3-selenium).
screenshot: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 scripts/screenshot.py

# Network faults on loopback, each test in its own network namespace with
# nftables (root): silent pulls, resets, random loss. make test runs it too,
# with the first native build.
.PHONY: test-faults
test-faults: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 tests/integration/test_faults.py

# docs/register-map.md is generated from the table in src/modbus/regmap_table.c,
# and so are the PLC library's constants (plc/jaka_map.st).
docs: $(BUILD)/jakagw man
	$(BUILD)/jakagw --print-map md > docs/register-map.md
	$(BUILD)/jakagw --print-map csv > docs/register-map.csv
	$(BUILD)/jakagw --print-map st > plc/jaka_map.st
	$(BUILD)/jakagw -c config/jakagw.conf --print-dbc > docs/jakagw.dbc

# The CAN mirror on a real kernel CAN stack: boots Debian's kernel in qemu
# (no KVM needed) with vcan, decodes the frames with docs/jakagw.dbc.
# tests/run.sh (make test) runs it too.
test-can: all
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 tests/can/test_can_vm.py

# Latency, jitter, reordering, duplication and a rate limit with sch_netem,
# in a VM of Debian's kernel (tests/can/vm.py). tests/run.sh runs it too.
test-netem: all $(BUILD)/tests/netem_plc
	JAKAGW_BIN_DIR=$(BUILD) /usr/bin/python3 tests/can/test_netem_vm.py

# Unit tests, then jakagw and jakasim themselves under valgrind in the
# integration suites that do not depend on timing (valgrind runs 20-50x slower).
valgrind: all unit-tests
	@BUILDS=build VALGRIND=1 tests/run.sh unit
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_status_map.py
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_modbus_server.py valgrind
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_jakasim.py
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_link_faults.py soak
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_service.py
	JAKAGW_VALGRIND=1 /usr/bin/python3 tests/integration/test_tls.py valgrind

# libFuzzer targets (clang; 'make deps DEPS_GROUPS=fuzz'), with ASan and
# UBSan: the robot's status stream, Modbus requests through the write path,
# the configuration parser, the command queue and its reply parser, the PLC
# mailboxes, the RTU framer, the motion tracker and the policy's judge of its
# action. UBSan's "undefined" leaves float-cast-overflow out (GCC's sanitizer
# build has none): clang adds it here, so a double converted out of range
# (a move's 1e999, a NaN bound) fails. make fuzz runs each for FUZZ_SECONDS, growing a
# corpus in $(FUZZ_BUILD)/corpus-*; make fuzz-ci runs each from the committed seeds
# with a 10 s hang limit, and a crash or hang fails it with one line naming
# the target and the input that caused it (CI runs it from make test).
FUZZ_SECONDS ?= 60
# make test under CI=true: each target from its seeds for this long (make
# fuzz is for longer runs); 0 leaves it out (.ci/run runs make fuzz-ci
# itself, beside amd64's tests).
CI_FUZZ_SECONDS ?= 10
FUZZ_BUILD ?= build-fuzz
FUZZ_TARGETS := fuzz_stream fuzz_modbus fuzz_config fuzz_command fuzz_mailbox fuzz_rtu fuzz_motion
FUZZ_MODULES := framer status json_arena regmap regmap_table mb_request log command plc_commands \
                param_rows output_readback \
                config can_map can_map_table plc_write policy ip_allow regmap_rights tls rtu_frame audit \
                motion json_member cmd_json
FUZZ_SRCS := $(foreach m,$(FUZZ_MODULES),$(wildcard src/*/$(m).c))
FUZZ_FLAGS := -std=c11 -D_DEFAULT_SOURCE -DJAKAGW_VERSION='"$(VERSION)"' -g -O1 $(INC_FLAGS) \
              $(PKG_CFLAGS) -fno-sanitize-recover=all
FUZZ_OBJS := $(FUZZ_SRCS:%.c=$(FUZZ_BUILD)/obj/%.o)
.SECONDARY: $(FUZZ_OBJS)
$(FUZZ_BUILD)/obj/%.o: %.c
	@mkdir -p $(dir $@)
	clang $(FUZZ_FLAGS) -fsanitize=fuzzer-no-link,address,undefined,float-cast-overflow -MMD -MP -c $< -o $@
$(FUZZ_BUILD)/%: fuzz/%.c fuzz/fuzz_robot.h fuzz/fuzz_util.h $(FUZZ_OBJS)
	clang $(FUZZ_FLAGS) -fsanitize=fuzzer,address,undefined,float-cast-overflow $< $(filter %.o,$^) -o $@ $(PKG_LIBS) -lm

fuzz-check:
	@command -v clang >/dev/null || { echo "make fuzz needs clang: make deps DEPS_GROUPS=fuzz" >&2; exit 1; }

fuzz: fuzz-check
	$(MAKE) -j$(JOBS) $(FUZZ_TARGETS:%=$(FUZZ_BUILD)/%)
	@for t in $(FUZZ_TARGETS); do \
	    mkdir -p $(FUZZ_BUILD)/corpus-$${t#fuzz_} && \
	    $(FUZZ_BUILD)/$$t -max_total_time=$(FUZZ_SECONDS) -timeout=10 \
	        $$([ $$t = fuzz_stream ] && echo -max_len=20000) \
	        $(FUZZ_BUILD)/corpus-$${t#fuzz_} fuzz/seeds/$${t#fuzz_} || exit 1; \
	done

fuzz-ci: fuzz-check
	$(MAKE) -j$(JOBS) $(FUZZ_TARGETS:%=$(FUZZ_BUILD)/%)
	@FUZZ_SECONDS=$(FUZZ_SECONDS) fuzz/run-ci.sh $(FUZZ_BUILD) $(FUZZ_TARGETS)

# The man pages: man/*.in with the options of --help, the keys of
# --print-config-keys and their descriptions in config/jakagw.conf.
man: $(BUILD)/jakagw $(BUILD)/jakasim
	/usr/bin/python3 scripts/gen-man.py $(BUILD) jakagw.8 > man/jakagw.8
	/usr/bin/python3 scripts/gen-man.py $(BUILD) jakasim.1 > man/jakasim.1

UNITS := jakagw.service jakagw@.service jakagw.socket jakagw-socket.service jakagw-mbaps.socket
# README.md and, beside it in docs/, the pages it links to.
DOCS  := $(wildcard docs/*.md docs/*.csv docs/*.dbc docs/*.yml docs/*.png)
CONF  := $(DESTDIR)$(SYSCONFDIR)/jakagw/jakagw.conf
# A configuration already there is the user's: it is never overwritten.
install: all
	install -d $(DESTDIR)$(SBINDIR) $(DESTDIR)$(BINDIR) $(DESTDIR)$(SYSCONFDIR)/jakagw \
	    $(DESTDIR)$(UNITDIR) $(DESTDIR)$(GENERATORDIR) $(DESTDIR)$(LIBEXECDIR) $(DESTDIR)$(DOCDIR)/docs $(DESTDIR)$(MANDIR)/man1 $(DESTDIR)$(MANDIR)/man8
	install -m 0755 $(BUILD)/jakagw $(DESTDIR)$(SBINDIR)/
	install -m 0755 $(BUILD)/jakasim $(DESTDIR)$(BINDIR)/
	@if [ -e $(CONF) ]; then \
	    install -m 0644 config/jakagw.conf $(CONF).dist; \
	    echo "install: $(CONF) exists and is kept; the new default configuration is $(CONF).dist"; \
	else \
	    echo "install -m 0644 config/jakagw.conf $(CONF)"; \
	    install -m 0644 config/jakagw.conf $(CONF); \
	fi
	for unit in $(UNITS); do \
	    sed 's|@SBINDIR@|$(SBINDIR)|g; s|@SYSCONFDIR@|$(SYSCONFDIR)|g; s|@DOCDIR@|$(DOCDIR)|g; s|@LIBEXECDIR@|$(LIBEXECDIR)|g' \
	        systemd/$$unit.in > $(DESTDIR)$(UNITDIR)/$$unit && \
	    chmod 0644 $(DESTDIR)$(UNITDIR)/$$unit || exit 1; \
	done
	sed 's|@SBINDIR@|$(SBINDIR)|g; s|@SYSCONFDIR@|$(SYSCONFDIR)|g' \
	    systemd/jakagw-generator.in > $(DESTDIR)$(GENERATORDIR)/jakagw-generator
	chmod 0755 $(DESTDIR)$(GENERATORDIR)/jakagw-generator
	sed 's|@SBINDIR@|$(SBINDIR)|g' systemd/jakagw-condition.in > $(DESTDIR)$(LIBEXECDIR)/jakagw-condition
	chmod 0755 $(DESTDIR)$(LIBEXECDIR)/jakagw-condition
	install -m 0644 man/jakagw.8 $(DESTDIR)$(MANDIR)/man8/
	install -m 0644 man/jakasim.1 $(DESTDIR)$(MANDIR)/man1/
	install -m 0644 README.md $(DESTDIR)$(DOCDIR)/
	install -m 0644 $(DOCS) $(DESTDIR)$(DOCDIR)/docs/
	@case "$(UNITDIR)" in /lib/systemd/system|/usr/lib/systemd/system|/usr/local/lib/systemd/system|/etc/systemd/system) ;; \
	*) echo "install: $(UNITDIR) is not on systemd's unit search path: 'systemctl link' the units there" ;; esac

# The configuration is left in place, as a package removal (not a purge) does.
uninstall:
	rm -f $(DESTDIR)$(SBINDIR)/jakagw $(DESTDIR)$(BINDIR)/jakagw $(DESTDIR)$(BINDIR)/jakasim \
	    $(addprefix $(DESTDIR)$(UNITDIR)/,$(UNITS)) $(DESTDIR)$(GENERATORDIR)/jakagw-generator \
	    $(DESTDIR)$(LIBEXECDIR)/jakagw-condition $(DESTDIR)$(MANDIR)/man8/jakagw.8 $(DESTDIR)$(MANDIR)/man1/jakasim.1
	rm -rf $(DESTDIR)$(DOCDIR)
	@echo "uninstall: $(DESTDIR)$(SYSCONFDIR)/jakagw is kept; remove it when its configuration is no longer wanted"

# The Debian package (dpkg-buildpackage -us -uc -b) from a copy of the
# source files, so that nothing in this tree is cleaned or rebuilt:
# $(BUILD)/deb/jakagw_$(VERSION)_ARCH.deb.
deb:
	@scripts/build-deb.sh $(BUILD)/deb $(if $(TRIPLET),$(ARCH) $(SYSROOT))

# Builds the package and installs it into a fresh Debian 12 root file
# system (mmdebstrap): files, enabled units, the conffile kept on upgrade,
# systemd-analyze verify and security, lintian. make test runs it.
test-package:
	@/usr/bin/python3 tests/package/test_package.py $(BUILD)

# The installed package under systemd as PID 1, in a VM (docs/service.md,
# "Tested under systemd"): make deb, a Debian 12 image with the package
# installed by apt (cached in $(BUILD)/service-vm/ while its inputs are
# unchanged), one qemu of this machine's kernel for every case (one boot,
# two reboots): fresh_install, ready, reload, watchdog, socket, instances,
# credential, journal, tls_only, credential_rtu, rtu, can, generator,
# condition_parser, failure_is_failure, writes_until_allowed,
# serial_port_taken, by_id_links, upgrade, upgrade_socket, upgrade_instance,
# both_enabled, socket_unconfigured, upgrade_from_previous, remove, purge,
# seccomp. make test runs it too, with the first build.
test-service:
	@/usr/bin/python3 tests/service/test_service_vm.py $(BUILD)

clean:
	rm -rf build build-san build-fuzz

# The build's dependency files: not the ARM sysroot's, nor those of the service
# VM's image while it is built (its root has files named *.d: invoke-rc.d).
-include $(shell find $(BUILD) -path $(BUILD)/sysroot -prune -o -path $(BUILD)/service-vm -prune -o -name '*.d' -type f -print 2>/dev/null)

# A cross build is made again when its sysroot is (new packages, headers).
ifneq ($(TRIPLET),)
$(LIB_OBJS) $(SIM_OBJS) $(MAIN_SRC:%.c=$(BUILD)/%.o) $(UNIT_TESTS:%=$(BUILD)/tests/%) \
    $(BUILD)/bench/ref_slave $(BUILD)/bench/bench_pipeline $(BUILD)/bench/bench_commands \
    $(BUILD)/bench/bench_modbus $(BUILD)/bench/bench_tls: $(SYSROOT)/.jakagw-sysroot
endif
-include $(wildcard $(FUZZ_BUILD)/obj/src/*/*.d)
