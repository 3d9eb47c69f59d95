# Two commands (README): `make demo` and `make test`. Each creates .venv when missing and installs kosmap into it;
# the demo needs only the runtime dependencies (the test extras, evo and pytest among them, add ~15 s to a fresh install),
# installed without byte-compiling them: Python compiles the modules the demo imports as it imports them.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.kosmap-installed
TEST_STAMP := $(VENV)/.kosmap-test-installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e .
	@touch $(STAMP)

# the suite starts many processes: byte-compile what the runtime install skipped (pip's own compile of it took 19 s
# of a fresh demo's 36 s install; compileall on both cores does the whole venv in ~13 s)
$(TEST_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/python -m compileall -q -j 0 $(VENV)/lib > /dev/null || true
	@touch $(TEST_STAMP)

demo: $(STAMP)
	$(BIN)/kosmap demo

test: $(TEST_STAMP)
	$(BIN)/python -m pytest -n 2 --dist loadfile -q

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache demo_out
