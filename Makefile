# episode-audit — `make demo` runs the main job on built-in tasks, `make test` runs the checks.
# Both create .venv (Python >= 3.10 required) and install what they need on first use.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: all venv test test-long lint typecheck pytest bench demo fixtures clean

all: test

$(STAMP): pyproject.toml setup.py episode_audit/record/_stepfast.c
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else "episode-audit needs Python >= 3.10")'
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# torch on its own first, with pyproject's pin: alone it resolves to a wheel already on the
	@# machine (e.g. a CPU build); inside the whole dev set, pip >= 25 picks PyPI's CUDA build (3 GB)
	$(BIN)/python -m pip install --quiet 'torch==2.13.*'
	@# the compiled step must build here (a C compiler and Python's headers): a failure stops
	@# make test rather than silently testing the pure-Python path alone
	EPISODE_AUDIT_REQUIRE_EXTENSION=1 $(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff format --check episode_audit episode_audit_pytest.py setup.py tests bench fixtures
	$(BIN)/ruff check episode_audit episode_audit_pytest.py setup.py tests bench fixtures

typecheck: $(STAMP)
	$(BIN)/mypy

# the single-env recorder's tests run twice: on the compiled step, and on the pure-Python one
# that machines without a C compiler take (the files must be the same: tests/record/test_fast.py)
PURE_TESTS := $(addprefix tests/record/test_,gym.py misbehaving.py stream.py disk_full.py \
	threads.py settings.py reward_wrappers.py)

pytest: $(STAMP)
	EPISODE_AUDIT_REQUIRE_EXTENSION=1 $(BIN)/python -m pytest -q -m "not slow"
	EPISODE_AUDIT_PURE_PYTHON=1 $(BIN)/python -m pytest -q -m "not slow" $(PURE_TESTS)

test: lint typecheck pytest

test-long: $(STAMP)
	$(BIN)/python -m pytest -q -s -m slow  # -s: the harnesses print their figures

bench: $(STAMP)
	$(BIN)/python bench/run.py

demo: $(STAMP)
	$(BIN)/python -m episode_audit.demo

fixtures: $(STAMP)
	$(BIN)/python fixtures/make_fixtures.py

clean:
	rm -rf $(VENV) build *.egg-info episode_audit/record/_stepfast.*.so .mypy_cache .ruff_cache demo-out demo-out-viewers
