# DeepCurrents: `make run` (set up + the trefoil's minimal surface on CPU), `make test` (set up + tests).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_DIR ?= outputs/quickstart

.PHONY: setup run test lint bench clean

setup: $(STAMP)

# torch first, pinned: an unpinned torch would pull a multi-GB CUDA build on a CPU machine
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[dev,sweeps,media]"
	touch $(STAMP)

run: setup
	$(BIN)/python train.py experiment=minimal_trefoil preset=cpu hydra.run.dir=$(RUN_DIR)
	@echo "Results in $(RUN_DIR): metrics.json, mesh.ply, mesh.png, checkpoints/last.ckpt"

test: setup
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check src tests benchmarks train.py

bench: setup
	$(BIN)/python benchmarks/train_step.py

clean:
	rm -rf outputs multirun wandb lightning_logs .pytest_cache
