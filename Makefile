# Two commands do everything: `make demo` and `make test`. Both install first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# --no-compile: pip compiled every installed file (6,527 here, 46 s of a fresh clone's 107 s
# of pip); .ci/compile_imported then compiles those that al5d and the tests import (about
# 1,000).
PIP    := $(BIN)/python -m pip --disable-pip-version-check
PIPI   := $(PIP) install --no-compile --quiet -c constraints.txt
# Python caches what it compiles (our sources, the tests' rewritten asserts) in __pycache__,
# which git ignores: an environment that turns that off makes every process compile them
# again (a fresh clone's server 0.3 s more each start; pytest's collection 3.6 -> 9.8 s
# in each of five processes).
unexport PYTHONDONTWRITEBYTECODE
STAMP  := $(VENV)/.installed
IFACES := $(VENV)/.al5d_interfaces
IFSRC  := interfaces/wheel_includes.cmake $(wildcard interfaces/al5d_interfaces/*.txt interfaces/al5d_interfaces/*.xml \
                     interfaces/al5d_interfaces/msg/* interfaces/al5d_interfaces/action/*)
# Standard message packages that are not on PyPI (control_msgs for MoveIt's
# controllers, tf2_msgs for /tf), one stamp each.
STDMSGS := $(VENV)/.control_msgs $(VENV)/.tf2_msgs

.PHONY: runtime install chromium gl faketime demo test bench soak lint clean

# What the server, the client and the demo need (`make demo`); `make test` adds the rest.
RUNTIME := $(VENV)/.installed-runtime
# The three message builds side by side (their cmake configure steps use one core each), C
# and Python only (interfaces/wheel_includes.cmake): 41 s here, 61 s with C++ as well. A
# fresh clone's `make demo`: 96 s (pip 40, messages 42, the demo 14), 129 s with C++; with
# pip's --no-compile and .ci/compile_imported 103 s (one run on a noisier day; 99 s before).
MSGS := $(IFACES) $(STDMSGS) build/COLCON_IGNORE
# What al5d's processes import (and, for `make install`, the tests), compiled once:
# pip installs without compiling (.ci/compile_imported says why).
BYTECODE_RUNTIME := $(VENV)/.bytecode-runtime
BYTECODE := $(VENV)/.bytecode
runtime: $(RUNTIME)
	@$(MAKE) --no-print-directory --output-sync=target -j3 $(BYTECODE_RUNTIME) $(AMENT_HOOK) gl
# The test tools' pip install (one core, much of it unpacking) and Chromium's apt install
# run beside the message builds: they need only the runtime's packages.
install: $(RUNTIME)
	@$(MAKE) --no-print-directory --output-sync=target -j5 $(BYTECODE) $(AMENT_HOOK) chromium gl faketime
$(BYTECODE_RUNTIME): $(MSGS) .ci/compile_imported
	$(BIN)/python .ci/compile_imported
	touch $@
$(BYTECODE): $(MSGS) $(STAMP) .ci/compile_imported
	$(BIN)/python .ci/compile_imported --tests
	touch $@

# Every version is pinned: pyproject.toml pins what we use, constraints.txt
# pins everything those bring along.
$(RUNTIME): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip==26.3
	$(PIPI) -e '.[ros,rosbuild,physics]'
	touch $@
# The tests', the web view's, colcon's and the benchmarks' packages.
$(STAMP): $(RUNTIME)
	$(PIPI) -e '.[dev,ros,rosbuild,colcon,bench,web,physics]'
	touch $(STAMP)

# The ROS messages and action, built with rosidl into the venv's prefix so that
# no environment script is needed at run time; skipped when up to date.
$(IFACES): $(RUNTIME) $(IFSRC)
	rm -rf build/al5d_interfaces && mkdir -p build
	. $(BIN)/activate && export AMENT_PREFIX_PATH="$$VIRTUAL_ENV" && \
	  cmake -S interfaces/al5d_interfaces -B build/al5d_interfaces -DBUILD_TESTING=OFF -DAL5D_PYTHON_ONLY=ON \
	    -DCMAKE_INSTALL_PREFIX="$$VIRTUAL_ENV" -DPython3_EXECUTABLE="$$VIRTUAL_ENV/bin/python" \
	    > build/cmake.log 2>&1 || (mkdir -p build; cat build/cmake.log; exit 1)
	cmake --build build/al5d_interfaces -j 2 > build/build.log 2>&1 || (tail -40 build/build.log; exit 1)
	cmake --install build/al5d_interfaces > build/install.log 2>&1 || (tail -20 build/install.log; exit 1)
	$(BIN)/python -c "import al5d_interfaces.msg, al5d_interfaces.action"
	touch $(IFACES)

# The venv as an ament prefix (docs/moveit.md, without a ROS install): local_setup scripts
# as a ROS install has them, and its activate sourcing them, so that colcon builds against
# the venv with nothing else to source or export, and a workspace's install/setup.*
# chains it. Written again when the hooks change (the activate's part between its markers).
AMENT_HOOK := $(VENV)/.ament-prefix
$(AMENT_HOOK): ros/venv/local_setup.sh ros/venv/activate.sh $(RUNTIME)
	sed 's|@PREFIX@|$(abspath $(VENV))|' ros/venv/local_setup.sh > $(VENV)/local_setup.sh
	for shell in bash zsh; do echo '. "$(abspath $(VENV))/local_setup.sh"' > $(VENV)/local_setup.$$shell; done
	sed -i '/^# >>> al5d/,/^# <<< al5d/d' $(BIN)/activate
	cat ros/venv/activate.sh >> $(BIN)/activate
	touch $@

# The cmake builds above are no packages: a colcon workspace that holds this repository
# (src/al5d) must not take their generated setup.py and CMakeLists.txt for some.
build/COLCON_IGNORE:
	mkdir -p build && echo "cmake builds of the Makefile, not packages" > $@

# control_msgs and tf2_msgs, built the same way, but only when the import fails:
# a user with a real ROS install keeps their own packages. A package we built
# ourselves (its package.xml in the venv says "built by al5d") is rebuilt when
# its sources change or its stamp is removed.
$(VENV)/.control_msgs: CHECK := control_msgs.msg, control_msgs.action
$(VENV)/.control_msgs: interfaces/wheel_includes.cmake $(wildcard interfaces/control_msgs/*.txt interfaces/control_msgs/*.xml \
                         interfaces/control_msgs/msg/* interfaces/control_msgs/action/*)
$(VENV)/.tf2_msgs: CHECK := tf2_msgs.msg
$(VENV)/.tf2_msgs: interfaces/wheel_includes.cmake $(wildcard interfaces/tf2_msgs/*.txt interfaces/tf2_msgs/*.xml interfaces/tf2_msgs/msg/*)
$(STDMSGS): $(VENV)/.%: $(RUNTIME)
	@if ! grep -qs "built by al5d" $(VENV)/share/$*/package.xml && \
	    $(BIN)/python -c "import $(CHECK)" 2>/dev/null; then \
	  echo "$*: already installed, not built"; touch $@; exit 0; fi; \
	echo "$*: building interfaces/$* into $(VENV)"; \
	rm -rf build/$* && mkdir -p build/$* && \
	. $(BIN)/activate && export AMENT_PREFIX_PATH="$$VIRTUAL_ENV" && \
	{ cmake -S interfaces/$* -B build/$* -DBUILD_TESTING=OFF -DAL5D_PYTHON_ONLY=ON \
	    -DCMAKE_INSTALL_PREFIX="$$VIRTUAL_ENV" -DPython3_EXECUTABLE="$$VIRTUAL_ENV/bin/python" \
	    > build/$*/cmake.log 2>&1 || { cat build/$*/cmake.log; exit 1; }; } && \
	{ cmake --build build/$* -j 2 > build/$*/build.log 2>&1 || { tail -40 build/$*/build.log; exit 1; }; } && \
	{ cmake --install build/$* > build/$*/install.log 2>&1 || { tail -20 build/$*/install.log; exit 1; }; } && \
	$(BIN)/python -c "import $(CHECK)" && touch $@

# The web view's browser test (tests/test_web.py) drives Debian's headless Chromium with
# playwright, which cannot download a browser of its own here. Installed when missing:
# the pinned version first; when apt no longer offers it (bookworm-security replaces it
# on each security release), the version apt offers, with a warning naming both (then
# update the pin to what `apt-cache policy chromium` offers). APT_GET, APT_CACHE and
# CHROMIUM_BIN are there to try the choice without apt: e.g.
#   make chromium CHROMIUM_BIN=none APT_GET='echo apt-get' APT_CACHE=./fake-apt-cache
CHROMIUM_VERSION := 156.0.8078.114-1~deb12u1
CHROMIUM_BIN ?= chromium
# Chromium's, the GL's and libfaketime's installs run side by side (make -j): each apt-get
# waits its turn on one lock of ours, as dpkg allows one at a time (seen on a fresh
# machine: "Could not get lock /var/lib/dpkg/lock-frontend", and the install failed).
APT_GET ?= flock /tmp/al5d-apt.lock apt-get
APT_CACHE ?= apt-cache
chromium:
	@command -v $(CHROMIUM_BIN) >/dev/null || { \
	  $(APT_GET) update -qq || exit 1; \
	  offered=$$($(APT_CACHE) madison chromium | awk -F'|' '{gsub(/ /, "", $$2); print $$2}'); \
	  if printf '%s\n' "$$offered" | grep -qxF '$(CHROMIUM_VERSION)'; then \
	    version='$(CHROMIUM_VERSION)'; \
	  else \
	    version=$$($(APT_CACHE) policy chromium | awk '/Candidate:/ {print $$2}'); \
	    case "$$version" in ""|"(none)") \
	      echo "chromium: apt offers no chromium (pinned $(CHROMIUM_VERSION))" >&2; exit 1;; \
	    esac; \
	    echo "WARNING: chromium $(CHROMIUM_VERSION) (the Makefile's pin) is no longer offered" \
	      "by apt; installing $$version, the version it offers. Update CHROMIUM_VERSION." >&2; \
	  fi; \
	  echo "chromium: installing $$version (apt-get)"; \
	  DEBIAN_FRONTEND=noninteractive $(APT_GET) install -y -qq \
	    --no-install-recommends "chromium=$$version" >/dev/null; }

# The physical twin's camera (al5d.twin) renders offscreen through EGL with Debian's Mesa on
# the CPU (llvmpipe): no display, no GPU. Installed when missing, the versions apt offers
# (Mesa's security releases replace them); GL_LIBDIR and APT_GET to try it without apt.
GL_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0
GL_LIBDIR ?= /usr/lib/x86_64-linux-gnu
gl:
	@if [ -e $(GL_LIBDIR)/libEGL_mesa.so.0 ] && [ -e $(GL_LIBDIR)/dri/swrast_dri.so ] && \
	    [ -e $(GL_LIBDIR)/libOpenGL.so.0 ] && [ -e $(GL_LIBDIR)/libEGL.so.1 ]; then :; else \
	  $(APT_GET) update -qq || exit 1; \
	  echo "gl: installing $(GL_PACKAGES) (apt-get)"; \
	  DEBIAN_FRONTEND=noninteractive $(APT_GET) install -y -qq --no-install-recommends \
	    $(GL_PACKAGES) >/dev/null; fi

# libfaketime, for the tests of clients whose clocks are seconds off (tests/test_ros_leases.py):
# Debian's, pinned; FAKETIME_LIB to try it without apt.
FAKETIME_VERSION := 0.9.10-2.1
FAKETIME_LIB ?= /usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1
faketime:
	@if [ -e $(FAKETIME_LIB) ]; then :; else \
	  $(APT_GET) update -qq || exit 1; \
	  echo "faketime: installing libfaketime $(FAKETIME_VERSION) (apt-get)"; \
	  DEBIAN_FRONTEND=noninteractive $(APT_GET) install -y -qq --no-install-recommends \
	    libfaketime=$(FAKETIME_VERSION) >/dev/null; fi

# The demo needs no browser, no test tools and no colcon: it runs once the runtime is in.
demo: runtime
	$(BIN)/al5d demo

# Four workers for most of the suite, then the load suites (marked solo) alone. It waits
# on servos, wires, DDS and the browser more than on the CPU (two workers kept the two
# cores a third busy; four, less than half): the parallel part took 469 s on two, 308 s
# on four here. Six took 211 s here, but 414 s on a CI machine, where two tests failed
# for it (a page not loaded in 30 s, a trajectory's writes late); four passed there.
# What four showed failing beside two busy loops: a move withheld for a stop got no outcome (fixed),
# the rig took a killed server's match for the new one's (fixed), a board thread of a busy
# test process answered later than 0.5 s (test servers now give it 1 s).
# The files that keep a worker longest go first (tests/conftest.py, LONGEST_FIRST), so that
# none starts near the end: xdist's own order (by the number of tests in a file) left the
# browser's files to the end.
# `make test WORKERS=2 DURATIONS=0` for another count and every test's time.
# Each part is interrupted (pytest then reports what ran and what failed) long after it
# should have ended: a CI run once waited out its 90 minutes on a stuck suite.
# A worker that crashes (a segmentation fault in a test's DDS, seen once) ends the part at
# once, naming its test: pytest-xdist 3.8's loadfile scheduling, replacing a crashed
# worker, can wait for ever (pytest-dev/pytest-xdist#784; a CI run hung until interrupted).
# On a machine already busy two workers (.ci/workers says which): four beside two busy
# loops starved the boards emulated in the test processes (no answer for 450 ms: a lost
# link) and a page's browser. Read when make starts, before the install (whose message
# builds make the machine look busy).
ifndef WORKERS
WORKERS   := $(shell python3 .ci/workers)
endif
export WORKERS  # the install's own makes then need not ask again
DURATIONS ?= 12
PART_S    ?= 1800
# The files of the solo part, so that it collects those alone.
SOLO      := $(shell grep -l '^pytestmark = pytest.mark.solo' tests/test_*.py)
test: install
	timeout -s INT -k 60 $(PART_S) \
	  $(BIN)/python -m pytest -q -n $(WORKERS) --dist loadfile --no-loadscope-reorder \
	  --max-worker-restart=0 -m "not solo" --durations=$(DURATIONS)
	timeout -s INT -k 60 $(PART_S) $(BIN)/python -m pytest -q -m solo $(SOLO)

bench: install
	$(BIN)/python bench/run.py

# The reliability suites, longer than in `make test`, with their figures (about 30 minutes):
# faults and floods, the link cut mid-move 20 times between two hosts (network namespaces), a
# server's owner frozen mid-move, the contention suite (several flooded servers beside busy loops, a
# goal flood at 9600 baud, ten minutes of false link faults at load 6), then the fuzz
# suites, the arm's model-based test and issue 22's sequences over DDS with ten times the
# cases.
soak: install
	$(BIN)/python bench/soak.py
	$(BIN)/python bench/network_cut.py
	$(BIN)/python bench/network_faults.py
	$(BIN)/python bench/network_restart.py
	$(BIN)/python bench/owner_silence.py
	$(BIN)/python bench/busy_host.py
	AL5D_FUZZ_SCALE=10 $(BIN)/python -m pytest -q -p no:cacheprovider -o timeout=1800 \
	  tests/test_fuzz_text.py tests/test_fuzz_ros.py tests/test_arm_model.py tests/test_ros_sequences.py

lint: install
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench
	$(BIN)/mypy

clean:
	rm -rf $(VENV) build
