# The README's two commands: `make run` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PROBLEM ?= problems/needle_regrasp.yaml
OUT    ?= out
# The lock: pinned versions of the run and test environments (Python 3.11, linux), written by `make lock`.
LOCK   := requirements/run.txt requirements/test.txt
LATEST := .venv-latest

.PHONY: run test install browser compiler clean package-check lock test-latest docs demo

# .venv from the lock (the test lock holds the run one's pins), then the package itself without dependencies.
$(STAMP): pyproject.toml $(LOCK)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements/test.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# Refresh the lock: the newest versions pyproject.toml allows, resolved by uv (the dev extra's tool) for
# CPython 3.11 on x86-64 linux; the test lock is constrained to the run lock's pins.
# `make lock LOCK_UPGRADE=` keeps the current pins and only adds or removes what pyproject.toml changed.
LOCK_UPGRADE ?= --upgrade
UV_COMPILE = $(VENV)/bin/uv pip compile --quiet $(LOCK_UPGRADE) --python-version 3.11 \
	--python-platform x86_64-unknown-linux-gnu --custom-compile-command "make lock" --annotation-style line pyproject.toml
lock:
	test -x $(VENV)/bin/uv || ($(PYTHON) -m venv $(VENV) && $(PY) -m pip install --quiet "uv>=0.5")
	$(UV_COMPILE) -o requirements/run.txt
	$(UV_COMPILE) --extra test --constraint requirements/run.txt -o requirements/test.txt

install: $(STAMP)

# Solve the default problem, compare the methods, write the visualisation.
run: $(STAMP)
	$(VENV)/bin/surestep compare $(PROBLEM) --output-dir $(OUT)/needle_regrasp
	$(VENV)/bin/surestep show $(OUT)/needle_regrasp --html $(OUT)/needle_regrasp.html

# Headless Chromium for the browser tests (Debian package), installed when missing.
browser:
	@command -v chromium >/dev/null 2>&1 || (command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "chromium not installed: browser tests will be skipped")

# The re-planning ROS 2 node (`surestep serve`) against a simulated PSM and tracker (`surestep sim-robot`), two
# processes over DDS confined to loopback (no multicast; the ros extra, in the test lock): ends once the goal is held.
DEMO_DDS = $(abspath $(OUT))/cyclonedds.xml
demo: $(STAMP)
	$(PY) -m surestep_ocp.ros.loopback $(DEMO_DDS) >/dev/null
	export CYCLONEDDS_URI=file://$(DEMO_DDS) OPENBLAS_NUM_THREADS=1; \
	$(VENV)/bin/surestep sim-robot $(PROBLEM) & sim=$$!; \
	$(VENV)/bin/surestep serve $(PROBLEM); code=$$?; kill -TERM $$sim; wait $$sim; exit $$code

# A C compiler for the compiled OCP derivatives (solver.codegen: auto uses it when present; the tests
# check the compiled path against the interpreted one), installed when missing.
compiler:
	@command -v $${CC:-gcc} >/dev/null 2>&1 || (command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc libc6-dev >/dev/null) \
	  || echo "no C compiler installed: the OCP runs interpreted, compiled-path tests will be skipped")

# The API reference from the docstrings (pdoc, in the test extra): docs/api/index.html. `make test` builds it
# too, into a temporary folder (tests/test_public_surface.py).
docs: $(STAMP)
	$(PY) docs/api_reference.py docs/api

test: $(STAMP) browser compiler
	$(PY) -m pytest -n 2 -q

# The tests against the newest releases pyproject.toml allows (CI's early warning; not part of `make test`):
# a fresh $(LATEST) with the test extra installed unpinned.
test-latest: browser compiler
	$(PYTHON) -m venv --clear $(LATEST)
	$(LATEST)/bin/python -m pip install --quiet --upgrade pip
	$(LATEST)/bin/python -m pip install --quiet --upgrade -e ".[test]"
	$(LATEST)/bin/python -m pip list --format=freeze | grep -iE "^(numpy|scipy|casadi|pin)=="
	$(LATEST)/bin/python -m pytest -n 2 -q

# The installable package from scratch: a wheel built from a clean clone of HEAD, installed with its
# dependencies from the package index into a fresh venv, solves a problem file copied to another folder.
# (Slow: it downloads and installs every dependency; `make test` runs a lighter version of it.)
PKG_TMP ?= /tmp/surestep-package-check
package-check:
	rm -rf $(PKG_TMP) && mkdir -p $(PKG_TMP)/elsewhere
	git clone -q . $(PKG_TMP)/clone
	$(PYTHON) -m venv $(PKG_TMP)/venv
	$(PKG_TMP)/venv/bin/python -m pip install --quiet --upgrade pip build
	cd $(PKG_TMP)/clone && $(PKG_TMP)/venv/bin/python -m build --wheel --outdir $(PKG_TMP)/dist >/dev/null
	$(PKG_TMP)/venv/bin/python -m pip install --quiet $(PKG_TMP)/dist/surestep_ocp-*.whl
	cp problems/needle_regrasp.yaml $(PKG_TMP)/elsewhere/copied.yaml
	cd $(PKG_TMP)/elsewhere && $(PKG_TMP)/venv/bin/surestep --version && \
	  $(PKG_TMP)/venv/bin/surestep validate problems/needle_regrasp.yaml && \
	  $(PKG_TMP)/venv/bin/surestep solve copied.yaml --method ocp --output ocp.json && \
	  $(PKG_TMP)/venv/bin/surestep export ocp.json --format ros2 --output ocp.yaml
	@echo "package-check: ok ($(PKG_TMP))"

clean:
	rm -rf $(VENV) $(LATEST) $(OUT)
