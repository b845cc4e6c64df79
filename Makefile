# Two commands: `make run` (set up + demo sweep of every agent) and `make test` (set up + tests).
VENV    ?= .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed-stamp
PYTHON3 ?= python3

.PHONY: run demo install test test-slow bench paper-figures ui clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON3) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first and pinned: 2.13.0 is a local CPU wheel; anything else downloads a multi-GB CUDA build
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev]"
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)  ## the main job: a few-minute demo (a drone learning to hover) of the paper's agents into ./mlflow.db
	$(PY) -m sweep -m experiment=demo
	$(PY) -m sweep.report --experiment recom-demo
	@echo "Results: MLflow store $(CURDIR)/mlflow.db (unless MLFLOW_TRACKING_URI is set); job outputs under multirun/"
	@echo "Open them:  source $(VENV)/bin/activate && mlflow ui      (or: make ui)"
	@echo "Runs table: $$($(PY) -m sweep.links recom-demo)"

demo: run

# Tests on every core (pytest-xdist), a test module per worker (--dist loadscope: its module fixtures, such as
# test_report's trained store, are built once), the longest modules first (tests/conftest.py, LONGEST_FIRST; xdist
# would order them by test count). `pytest tests/test_x.py` alone runs in one process.
TEST_WORKERS ?= auto

test: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadscope --no-loadscope-reorder

test-slow: $(STAMP)
	$(PY) -m pytest -m slow -n $(TEST_WORKERS) --dist loadscope --no-loadscope-reorder

bench: $(STAMP)
	$(PY) benchmarks/bench.py

paper-figures: $(STAMP)
	$(PY) -m sweep.report

ui: $(STAMP)  ## MLflow UI on 127.0.0.1:5000 with one worker (~0.5 GB instead of ~2.7 GB)
	@$(PY) -m sweep.links
	MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false MLFLOW_DISABLE_TELEMETRY=true $(VENV)/bin/mlflow ui --workers 1

clean:
	rm -rf outputs reports .pytest_cache
	find multirun -mindepth 1 -not -name .gitkeep -delete 2>/dev/null || true
	find . -name __pycache__ -prune -exec rm -rf {} +
