# Every target sets itself up: a fresh machine needs only python3 and make.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
DEMO_STAMP := $(VENV)/.demo-stamp
PYTEST_ARGS ?=
# The suite's worker processes (pytest-xdist; 0: one process). Three on two cores take it
# from about 19 min to 4-10 (docs/architecture.md says what that asks of a test).
PYTEST_WORKERS ?= 3

.PHONY: setup test test-pure lint demo bench clean iverilog cc cmake firmware tf2-msgs compile pure

# The demo's set-up: the package and matplotlib for step.png, nothing else (docs/install.md
# gives the size). The install compiles the emulator with mypyc where a C compiler is found
# (the build hook, hatch_build.py), in place beside the sources; without one, or with
# FPGALINK_PURE=1, it is pure Python, said in one line.
# Not every module is byte-compiled at install (--no-compile: 45 MB less), but the package
# and what a command imports are (tools/precompile.py, a few MB): where
# PYTHONDONTWRITEBYTECODE=1 is set nothing is written at run time, and each command compiled
# them again. setuptools, which venv adds on Python 3.11 and nothing here imports, is taken
# out (9 MB; builds bring their own).
BYTECODE_PACKAGES := fpgalink fpgaemu click rich serial construct mcap numpy
$(DEMO_STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --no-compile --upgrade pip
	$(PY) -m pip install --quiet --no-compile -e '.[plot]'
	$(PY) -m pip uninstall --quiet --yes setuptools 2>/dev/null || true
	$(PY) tools/precompile.py $(BYTECODE_PACKAGES)
	touch $(DEMO_STAMP)

# The test set-up is every extra: the ros2 extra (ROS 2 Jazzy's PyPI wheels and rosbags;
# its transitive pins are in ros2-constraints.txt), the physics body (MuJoCo), the C
# co-simulation, the benchmarks' peers and the developer tools; setuptools back (cffi
# and the compiled build build through it). The package itself is as the demo's install
# left it (no build hook: the compiled build is not made a second time; `make compile`
# keeps it up to date).
$(STAMP): $(DEMO_STAMP) ros2-constraints.txt
	HATCH_BUILD_NO_HOOKS=true $(PY) -m pip install --quiet -e '.[dev,ros2,physics,cosim,bench,plot,campaign]' setuptools -c ros2-constraints.txt
	touch $(STAMP)

# Icarus Verilog simulates the reference UART the emulator's is checked against
# (tests/fpgaemu/test_uart_hdl.py); a Debian package.
ICARUS := $(shell command -v iverilog 2>/dev/null)
iverilog:
ifeq ($(ICARUS),)
	@if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq iverilog >/dev/null; \
	else sudo apt-get update -qq && sudo apt-get install -y -qq iverilog >/dev/null; fi
endif

# A C compiler builds the C firmware core the emulator can run in place of its Python model
# (fpgaemu.cfirmware, tests parametrised over both) and the generated protocol codec.
CC_FOUND := $(shell command -v cc 2>/dev/null || command -v gcc 2>/dev/null)
cc:
ifeq ($(CC_FOUND),)
	@if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq gcc libc6-dev >/dev/null; \
	else sudo apt-get update -qq && sudo apt-get install -y -qq gcc libc6-dev >/dev/null; fi
endif

# CMake builds tf2_msgs (below) with the rosidl generators; a Debian package.
CMAKE_FOUND := $(shell command -v cmake 2>/dev/null)
cmake:
ifeq ($(CMAKE_FOUND),)
	@if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq cmake >/dev/null; \
	else sudo apt-get update -qq && sudo apt-get install -y -qq cmake >/dev/null; fi
endif

# tf2_msgs (/tf, /tf_static) has no Jazzy wheel on PyPI: generated from the rosidl wheels that
# are, its type hash checked against Jazzy's, installed into the venv (fpgalink.ros2.tf2build,
# which a pip user runs as `fpgalink-ros2 --install-tf2`). Part of the tests' set-up only: the
# node runs without /tf where it is absent.
TF2_SOURCE := src/fpgalink/ros2/tf2_msgs_source
TF2_STAMP := $(VENV)/.tf2-msgs-stamp
$(TF2_STAMP): $(STAMP) src/fpgalink/ros2/tf2build.py $(TF2_SOURCE)/requirements.txt \
		$(TF2_SOURCE)/CMakeLists.txt $(TF2_SOURCE)/package.xml $(TF2_SOURCE)/msg/TFMessage.msg
	$(PY) -m pip install --quiet -r $(TF2_SOURCE)/requirements.txt -c ros2-constraints.txt
	$(PY) -m fpgalink.ros2.tf2build --no-requirements
	touch $(TF2_STAMP)

tf2-msgs: cmake cc
	@$(MAKE) --no-print-directory $(TF2_STAMP)

# The firmware core and the protocol code generated for it, built for this host (sizes printed).
firmware: $(STAMP) cc
	$(MAKE) -C firmware PYTHON=$(abspath $(PY))

setup: $(STAMP)

# The compiled build (mypyc; build_support/mypyc_build.py lists the modules): in place,
# beside the sources in src/, remade whenever one of them is newer than the last build. A
# source changed since is never shadowed by its stale extension: at import it runs pure
# Python instead, saying `make compile` rebuilds it (fpgalink/buildinfo.py). `make pure`
# removes the compiled modules; FPGALINK_PURE=1 (at build or at run time) is pure Python.
COMPILED_MANIFEST := src/fpgalink/_compiled.txt
COMPILED_SOURCES := $(wildcard src/fpgaemu/*.py src/fpgalink/protocol/*.py \
	src/fpgalink/connection/*.py src/fpgalink/boardclock.py src/fpgalink/robot/*.py)
$(COMPILED_MANIFEST): build_support/mypyc_build.py $(COMPILED_SOURCES) | $(STAMP) cc
	$(PY) build_support/mypyc_build.py

compile: $(COMPILED_MANIFEST)

pure:
	python3 build_support/mypyc_build.py --clean

# pytest exits 5 when it collected nothing: say so plainly instead of passing it off as a failure of some test.
# --dist loadfile: a file's tests in one worker, so a module's fixture (the ROS 2 scenarios)
# starts once.
# The whole suite runs on the compiled build; then the exactness tests (the golden trace,
# the C core's co-simulation, which build runs) run again on pure Python, which is a
# first-class build (tests/fpgaemu/test_compiled.py compares the two state by state).
EXACTNESS_TESTS := tests/fpgaemu/test_golden_trace.py tests/fpgaemu/test_cfirmware.py \
	tests/test_build.py tests/fpgalink/protocol/test_telemetry_runs.py \
	tests/fpgalink/protocol/test_framing.py
PURE_RUN = echo "make test: the exactness tests on pure Python (FPGALINK_PURE=1)"; \
	FPGALINK_PURE=1 FPGALINK_REQUIRE_CC=1 $(PY) -m pytest -n $(PYTEST_WORKERS) \
	  --dist loadfile $(EXACTNESS_TESTS)
test: $(STAMP) iverilog cc tf2-msgs compile
	@FPGALINK_REQUIRE_HDL=1 FPGALINK_REQUIRE_ROS2=1 FPGALINK_REQUIRE_CC=1 \
	  FPGALINK_REQUIRE_COMPILED=1 $(PY) -m pytest -n $(PYTEST_WORKERS) --dist loadfile \
	  $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests"; fi; \
	$(PURE_RUN); pure=$$?; \
	if [ $$rc -eq 0 ]; then rc=$$pure; fi; exit $$rc

test-pure: $(STAMP) cc
	@$(PURE_RUN)

# The main job on the built-in emulator, no hardware: connect, enable, show the parameters,
# then a 0 -> 45 deg/s step on channel A with its metrics and a plot in step.png. The first
# command says that the built-in emulator stands in; the second names it, so it is said once.
demo: $(DEMO_STAMP)
	$(VENV)/bin/fpgalink-cli param list
	$(VENV)/bin/fpgalink-cli step --channel A --to 45 --hold 2 --plot step.png --force --port emu://

lint: $(STAMP)
	$(PY) -m ruff check src tests benchmarks
	$(PY) -m mypy

# As modules from the repository root, so they import benchmarks._common and the tests'
# reference models by their package names.
bench: $(STAMP) compile
	$(PY) -m benchmarks.codec
	$(PY) -m benchmarks.emulator
	$(PY) -m benchmarks.instructions
	$(PY) -m benchmarks.link
	$(PY) -m benchmarks.throughput
	$(PY) -m benchmarks.ros2
	$(PY) -m benchmarks.crc_ber
	$(PY) -m benchmarks.flood --mb 5
	$(PY) -m benchmarks.faults
	$(PY) -m benchmarks.router
	$(PY) -m benchmarks.recording
	$(PY) -m benchmarks.campaign
	$(PY) -m benchmarks.ceiling
	$(PY) -m benchmarks.identity

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache build dist firmware/build
	python3 build_support/mypyc_build.py --clean
