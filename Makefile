# jointseg: `make run` sets up a fresh machine and runs the main job; `make test` runs every check.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  ?= torch==2.13.0
DEMO   ?= demo
PORT   ?= 8000

.PHONY: setup system run serve test lint typecheck pytest docs docs-build clean

setup: system $(VENV)/.installed

system:
	bash scripts/setup_system.sh

# torch first, pinned: an unpinned torch would pull the multi-GB CUDA build.
$(VENV)/.installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[dev,ml3d]"
	touch $@

run: setup
	mkdir -p $(DEMO)
	$(BIN)/jointseg synth --seed 0 --points 1000000 -o $(DEMO)/room.ply
	$(BIN)/jointseg info $(DEMO)/room.ply
	bash scripts/demo_service.sh $(DEMO)/room.ply $(DEMO)/room_segmented.ply $(DEMO)/report.json $(DEMO)/data $(PORT)

# the job service in the foreground (API, worker, viewer; Ctrl-C stops all)
serve: setup
	$(BIN)/jointseg serve --port $(PORT) --data-dir $(DEMO)/data

lint: setup
	$(BIN)/ruff check jointseg server web tests bench docs/hooks
	$(BIN)/mypy

pytest: setup
	$(BIN)/python -m pytest -q

# the documentation site (docs/, mkdocs.yml): --strict fails on a broken link, a page missing
# from the nav or a docstring that does not render
docs-build: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

docs: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve --dev-addr 127.0.0.1:8001

test: lint pytest docs-build

clean:
	rm -rf $(VENV) $(DEMO) site .pytest_cache .ruff_cache .mypy_cache
