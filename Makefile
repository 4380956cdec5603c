# jointseg: `make run` sets up a fresh machine and runs the main job; `make test` runs every check.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  ?= torch==2.13.0
DEMO   ?= demo
PORT   ?= 8000

.PHONY: setup system run serve test test-fast lint typecheck pytest docs docs-build clean gpu-pack \
	gpu-train

setup: system $(VENV)/.installed

system:
	bash scripts/setup_system.sh

# torch first, pinned: an unpinned torch would pull the multi-GB CUDA build.
$(VENV)/.installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[dev,ml3d,openvino]"
	touch $@

run: setup
	mkdir -p $(DEMO)
	$(BIN)/jointseg synth --seed 0 --points 1000000 -o $(DEMO)/room.ply
	$(BIN)/jointseg info $(DEMO)/room.ply
	bash scripts/demo_service.sh $(DEMO)/room.ply $(DEMO)/room_segmented.ply $(DEMO)/report.json $(DEMO)/data $(PORT)

# the job service in the foreground (API, worker, viewer; Ctrl-C stops all)
serve: setup
	$(BIN)/jointseg serve --port $(PORT) --data-dir $(DEMO)/data

# ruff, mypy, the floors of docs/ARCHITECTURE.md (import-linter's contracts in pyproject.toml)
# and every module the shipped packages import declared as a dependency (deptry)
lint: setup
	$(BIN)/ruff check jointseg server web tests bench docs/hooks scripts
	$(BIN)/ruff format --check jointseg server web tests bench docs/hooks scripts
	$(BIN)/mypy
	$(BIN)/lint-imports --no-logo
	$(BIN)/deptry jointseg server web

# the whole suite in two runs (docs/contributing.md): the library, CLI and unit tests on two
# xdist workers, one test file to a worker (a module's fixtures are built once); then the
# service and browser tests one at a time (their servers, workers and chromium want both cores,
# and their process tests time signals). Each run ends with its 20 slowest tests.
pytest: setup
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not service and not browser" --durations=20
	$(BIN)/python -m pytest -q -m "service or browser" --durations=20

# the unit tests only, under 3 minutes on 2 cores: no chromium, no service processes or
# databases, nothing marked slow (pyproject.toml's markers; docs/contributing.md)
test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow and not service and not browser"

# the documentation site (docs/, mkdocs.yml): --strict fails on a broken link, a page missing
# from the nav or a docstring that does not render
docs-build: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

docs: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve --dev-addr 127.0.0.1:8001

# the suite builds the site itself (tests/docs/test_site.py: mkdocs build --strict), so the
# docs-build target is not run a second time here
test: lint pytest

# the prepared GPU run (docs/guide/gpu.md): gpu-pack here (wheels for the GPU machine's Python and
# the training data, into the ignored .gpu/), then on the lent machine, with .gpu carried:
# make gpu-train MINUTES=8 (writes into $$OUT)
GPU_WHEELS := pydantic==2.14.3 pydantic_core==2.50.4 annotated-types==0.8.0 \
	typing-inspection==0.4.5 laspy==2.7.0 lazrs==0.8.2 plyfile==1.1.5
MINUTES ?= 8
SHARED  ?= ../shared/data

gpu-pack: setup
	$(BIN)/pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
		--implementation cp --platform manylinux_2_28_x86_64 --platform manylinux2014_x86_64 \
		-d .gpu/wheels $(GPU_WHEELS)
	rm -rf .gpu/data
	$(BIN)/python -m jointseg.training.prepared pack --shared $(SHARED) --out .gpu/data
	$(BIN)/python -m jointseg.training.pseudo_pack --shared $(SHARED) --out .gpu/data
	du -sh .gpu

gpu-train:
	bash scripts/gpu_train.sh $(MINUTES)

clean:
	rm -rf $(VENV) $(DEMO) site .pytest_cache .ruff_cache .mypy_cache
