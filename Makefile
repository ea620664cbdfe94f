# The README's two commands: `make run` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PROBLEM ?= problems/needle_regrasp.yaml
OUT    ?= out

.PHONY: run test install browser compiler clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

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

# A C compiler for the compiled OCP derivatives (solver.codegen: auto uses it when present; the tests
# check the compiled path against the interpreted one), installed when missing.
compiler:
	@command -v $${CC:-gcc} >/dev/null 2>&1 || (command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc libc6-dev >/dev/null) \
	  || echo "no C compiler installed: the OCP runs interpreted, compiled-path tests will be skipped")

test: $(STAMP) browser compiler
	$(PY) -m pytest -n 2 -q

clean:
	rm -rf $(VENV) $(OUT)
