# The two set-up commands of the README: `make demo` and `make test`.
# Both create .venv when absent and install the project into it, with torch pinned by
# constraints.txt so pip never pulls a second torch or CUDA packages.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export NO_ALBUMENTATIONS_UPDATE := 1

.PHONY: install demo test lint typecheck format clean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt claravid/dsp/_deldensity.c claravid/io/_jpeg_region.c
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

# The evaluation is the one claravid-train suggests: the checkpoint's data, split and palette,
# into the run folder's report/ (tests/claravid/test_demo.py checks they agree).
demo: $(STAMP)
	$(BIN)/claravid-demo -o runs/demo
	$(BIN)/claravid-train --config demo --resume
	$(BIN)/claravid-eval --checkpoint runs/demo/train/best.pt --output runs/demo/train/report

# A worker per core, at most 4 (each holds its own session fixtures: a many-core machine would
# spend memory, not time); the 20 slowest tests printed at the end (docs/contributing.md).
test: lint
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadfile --durations=20

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MAKE) --no-print-directory typecheck

# mypy reads the package as it installs (models/ is claravid.models, as pyproject.toml's
# package-dir says) through a tree of links, made anew each time so new modules are seen.
TYPECHECK_TREE := build/typecheck/claravid
typecheck: $(STAMP)
	rm -rf build/typecheck
	mkdir -p $(TYPECHECK_TREE)
	ln -s $(CURDIR)/claravid/* $(TYPECHECK_TREE)/
	for folder in configs eval models train; do ln -s $(CURDIR)/$$folder $(TYPECHECK_TREE)/; done
	$(BIN)/mypy

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf runs build/typecheck .pytest_cache .ruff_cache .mypy_cache
