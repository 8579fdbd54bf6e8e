# The two commands a user needs: `make run` and `make test`. Both bootstrap .venv first.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
RUN_STAMP := $(VENV)/.run-stamp
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
SRC := app tests benchmarks client

.PHONY: run test venv run-venv chromium wrk lint format bench screenshots clean

## What running needs: the service's distribution, which holds the client (advisor_client) too.
## The client's own distribution (client/) is for agents without the service: a .venv made
## before it came with the service has it installed twice, so it goes.
$(RUN_STAMP): pyproject.toml client/pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	-@$(BIN)/python -m pip uninstall -q -y hidden-goal-advisor-client 2>/dev/null
	$(BIN)/python -m pip install -q -e .
	@touch $(RUN_STAMP)

## The same with the dev tools (tests, linters, the browser driver, Gymnasium and MiniGrid).
$(STAMP): pyproject.toml client/pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	-@$(BIN)/python -m pip uninstall -q -y hidden-goal-advisor-client 2>/dev/null
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP) $(RUN_STAMP)

venv: $(STAMP)

run-venv: $(RUN_STAMP)

## Installs a Debian package when its command is missing: one install at a time (flock), so
## that two checkouts set up side by side do not race for apt's lock; the command is looked
## for again once the lock is held.
APT_LOCK := /tmp/hidden-goal-advisor-apt.lock
define apt_install
	@command -v $(1) >/dev/null 2>&1 || flock $(APT_LOCK) sh -c '\
		command -v $(1) >/dev/null 2>&1 || { \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(1) >/dev/null; }'
endef

## Debian's chromium for the browser tests (Playwright cannot download browsers here).
chromium:
	$(call apt_install,chromium)

## Debian's wrk drives the HTTP benchmarks (installed the same way when missing).
wrk:
	$(call apt_install,wrk)

lint: venv
	$(BIN)/ruff check $(SRC)
	$(BIN)/ruff format --check $(SRC)
	$(BIN)/mypy app tests client/advisor_client

format: venv
	$(BIN)/ruff format $(SRC)
	$(BIN)/ruff check --fix $(SRC)

## Runs the whole suite; pytest exits non-zero (5) when no test ran, which fails the target.
## TEST_WORKERS processes (pytest-xdist) share the tests, a file's tests in one of them
## (`--dist loadfile`: a module's fixtures, such as its live server, are made once); `make test
## TEST_WORKERS=0` runs them in this one process. The slowest 25 are listed at the end.
TEST_WORKERS ?= 2
test: venv chromium lint
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --durations=25

## The browser tests, then their screenshots of every page copied into docs/screenshots/
## (README.md, "Pages"). `make test` leaves docs/ alone: its screenshots stay in test-artifacts/.
screenshots: venv chromium
	$(BIN)/python -m tests.browser.screenshots

## The service on 127.0.0.1:8000 with the viewer on :8080; SQLite and the admin key under ./data.
run: run-venv
	$(BIN)/python -m app serve

## Every benchmark under benchmarks/ (never part of `make test`): about 25 minutes on 2 quiet
## cores, more on busy ones; each rewrites its own section of docs/PERFORMANCE.md (bench_hostile
## its combined load's and its Redis pause's in docs/RELIABILITY.md, the pause with a
## redis-server of its own; bench_minigrid docs/RESULTS.md; bench_scaling
## and bench_service the curves in docs/figures/). bench_mqtt runs Debian's mosquitto;
## bench_workers the machine's Redis; bench_redis_costs prints what docs/SCALING.md quotes of it.
bench: venv wrk
	$(BIN)/python benchmarks/bench_core.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_scaling.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_experiments.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_viewer.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_service.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_ops.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_mqtt.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_minigrid.py --write docs/RESULTS.md
	$(BIN)/python benchmarks/bench_buildings.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_hostile.py --only combined --write docs/RELIABILITY.md
	$(BIN)/python benchmarks/bench_hostile.py --only redis_pause --write docs/RELIABILITY.md
	$(BIN)/python benchmarks/bench_workers.py --write docs/PERFORMANCE.md
	$(BIN)/python benchmarks/bench_redis_costs.py
	$(BIN)/python benchmarks/rest_inprocess.py
	$(BIN)/python benchmarks/sessions_inprocess.py

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .hypothesis
