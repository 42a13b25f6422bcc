# jax-contact: `make demo` and `make test` work on a fresh clone of a fresh machine.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Two pytest-xdist workers, one per core here; each file runs whole on one worker, so its
# module fixtures compile once. `make test TEST_WORKERS=0` runs it in one process.
# A worker that dies (a segmentation fault inside XLA's CPU compiler, seen in 2 of 4 whole
# runs on 2026-12-07, docs/performance.md) fails its test and is not replaced: replaced, it
# re-ran the same file or left pytest-xdist waiting with both workers idle until killed.
TEST_WORKERS ?= 2

.PHONY: demo test install lint clean clean-cache

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jax-contact demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist loadfile \
		--max-worker-restart=0

lint: $(STAMP)
	$(VENV)/bin/ruff check jax_contact envs train tests benchmarks notebooks
	$(VENV)/bin/ruff format --check jax_contact envs train tests benchmarks notebooks

clean:
	rm -rf $(VENV) out .pytest_cache

# JAX's persistent compilation cache of the CLI and the tests (train/cli.py; one subfolder
# per CPU feature set); `make demo` and `make test` fill it, a second run loads from it.
# Safe to delete at any time.
JAX_CONTACT_CACHE_DIR ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/jax-contact/xla
clean-cache:
	rm -rf "$(JAX_CONTACT_CACHE_DIR)"
