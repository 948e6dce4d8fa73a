# episode-audit — `make demo` runs the main job on built-in tasks, `make test` runs the checks.
# Both create .venv (Python >= 3.10 required) and install what they need on first use.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl
# Python caches what it compiles (.venv's site-packages, and __pycache__ in this tree, which git
# ignores): with PYTHONDONTWRITEBYTECODE set, every interpreter the tests start would compile
# its imports again (~760 modules, ~2.8 s each time: see docs/cli.md, "Start-up time")
unexport PYTHONDONTWRITEBYTECODE

.PHONY: all venv test test-long test-pythons lint typecheck pytest bench demo fixtures clean

all: test

$(STAMP): pyproject.toml setup.py $(wildcard episode_audit/record/csrc/*.[ch])
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else "episode-audit needs Python >= 3.10")'
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@# --no-compile: pip byte-compiles every installed file (torch, ray: ~70 s); Python compiles
	@# what a run imports on first import instead, and caches it (see unexport above)
	$(BIN)/python -m pip install --quiet --no-compile --upgrade pip uv
	@# torch on its own first, with pip and pyproject's pin: alone it resolves to a wheel already
	@# on the machine (e.g. a CPU build; uv reads no pip.conf, so it would fetch PyPI's CUDA build)
	$(BIN)/python -m pip install --quiet --no-compile 'torch==2.13.*'
	@# the rest with uv (parallel downloads and installs: ~15 s where pip takes ~100 s); it keeps
	@# the torch already installed, which satisfies the pin. The compiled step must build here (a
	@# C compiler and Python's headers): a failure stops make test rather than silently testing
	@# the pure-Python path alone
	EPISODE_AUDIT_REQUIRE_EXTENSION=1 $(BIN)/python -m uv pip install --quiet --python $(BIN)/python -e '.[dev]'
	@touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff format --check episode_audit episode_audit_cli.py episode_audit_pytest.py conftest.py setup.py tests bench fixtures
	$(BIN)/ruff check episode_audit episode_audit_cli.py episode_audit_pytest.py conftest.py setup.py tests bench fixtures

typecheck: $(STAMP)
	$(BIN)/mypy

# the recorders' tests run twice: on the compiled step, and on the pure-Python one that
# machines without a C compiler take (the files must be the same: tests/record/test_fast.py)
PURE_TESTS := $(addprefix tests/record/test_,gym.py misbehaving.py stream.py disk_full.py \
	threads.py settings.py reward_wrappers.py vector.py)

# -n 2 --dist loadfile: two worker processes, each test file whole on one of them (its
# module-scoped fixtures built once; one Ray, one moto server per file); a worker that crashes
# fails the run at once (--max-worker-restart=0) rather than being restarted to crash again
pytest: $(STAMP)
	EPISODE_AUDIT_REQUIRE_EXTENSION=1 $(BIN)/python -m pytest -q -m "not slow" -n 2 --dist loadfile --max-worker-restart=0
	EPISODE_AUDIT_PURE_PYTHON=1 $(BIN)/python -m pytest -q -m "not slow" -n 2 --dist loadfile --max-worker-restart=0 $(PURE_TESTS)

test: lint typecheck pytest

test-long: $(STAMP)
	$(BIN)/python -m pytest -q -s -m slow  # -s: the harnesses print their figures

# the suite ("not slow") on every other CPython >= 3.10 that pyenv has (or PYTHONS="python3.12
# ..."), each in .venv-X.Y with the dev extra but SB3 and torch, the oldest on pyproject's
# floors; then on this Python with the oldest SB3 allowed, in .venv-sb3: tests/pythons.py
test-pythons: $(STAMP)
	$(BIN)/python tests/pythons.py $(PYTHONS)

bench: $(STAMP)
	$(BIN)/python bench/run.py

demo: $(STAMP)
	$(BIN)/python -m episode_audit.demo

fixtures: $(STAMP)
	$(BIN)/python fixtures/make_fixtures.py

clean:
	rm -rf $(VENV) .venv-3.* build *.egg-info episode_audit/record/_stepfast.*.so .mypy_cache .ruff_cache demo-out demo-out-viewers
