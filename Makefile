# DeepCurrents: `make run` (set up + the trefoil's minimal surface on CPU), `make test` (set up + tests).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_DIR ?= outputs/quickstart

.PHONY: setup run test test-fast lint bench clean data docs docs-serve tutorial

setup: $(STAMP)

# torch first, pinned: an unpinned torch would pull a multi-GB CUDA build on a CPU machine
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[dev,sweeps,media,docs]"
	touch $(STAMP)

# the Anny extra and its one-time cache (~0.8 GB in ~/.cache/anny), built once here so that `make data` and the
# generator's test then take seconds
ANNY_STAMP := $(VENV)/.anny
$(ANNY_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -e ".[anny]"
	$(BIN)/python -c "import anny; anny.Anny(skinning_method='lbs')"
	touch $(ANNY_STAMP)

# human-part datasets, offline: data/anny/<heads|hands|forearms|arms|torsos|feet>/NNN.ply (100 bodies), and
# whole bodies cut into parts that share their loops, data/anny/bodies/NNN/ (experiment=stitched_body), and hands
# and forearms joined at the wrist in each body's wrist frame, data/anny/joined/wrist.L/ (families generated together)
DATA_BODIES ?= 100
DATA_WHOLE_BODIES ?= 4
DATA_JOINED ?= 8
data: $(ANNY_STAMP)
	$(BIN)/python -m deepcurrents.cli.make_dataset --source anny --num $(DATA_BODIES) \
		--whole-bodies $(DATA_WHOLE_BODIES) --joined-parts $(DATA_JOINED) --out data

# the quick start: the trefoil's minimal surface, 1500 steps of preset=cpu with the fast recipe (recipe=sharp);
# `make run RUN_RECIPE=` runs preset=cpu alone, `make run RUN_RECIPE= RUN_STEPS=3000` the preset's whole budget
RUN_STEPS ?= 1500
RUN_RECIPE ?= recipe=sharp
run: setup
	$(BIN)/python train.py experiment=minimal_trefoil preset=cpu $(RUN_RECIPE) trainer.max_steps=$(RUN_STEPS) \
		hydra.run.dir=$(RUN_DIR)
	@echo "Results in $(RUN_DIR): metrics.json, mesh.ply, mesh_polished.ply, mesh.png, render.png, checkpoints/last.ckpt"

# every test, on one pytest-xdist worker per core (at most TEST_WORKERS_MAX: each worker holds torch and Lightning,
# ~1 GB); `make test TEST_WORKERS=0` runs them in one process. `make test-fast` skips the ones marked slow.
TEST_WORKERS ?= auto
TEST_WORKERS_MAX ?= 4
PYTEST := $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --maxprocesses=$(TEST_WORKERS_MAX)
test: setup $(ANNY_STAMP)
	$(PYTEST)

test-fast: setup
	$(PYTEST) -m "not slow"

lint: setup
	$(BIN)/ruff check src tests benchmarks train.py

# the documentation site into site/, warnings (broken links, missing references) as errors; docs-serve previews it
docs: setup
	$(BIN)/mkdocs build --strict

docs-serve: setup
	$(BIN)/mkdocs serve

# the tutorial notebook run at full size with its outputs kept, as the site shows it (the tests run it tiny)
tutorial: setup
	cd docs/tutorials && ../../$(BIN)/jupyter-execute --inplace tutorial.ipynb

bench: setup
	$(BIN)/python benchmarks/train_step.py

clean:
	rm -rf outputs multirun wandb lightning_logs .pytest_cache site
