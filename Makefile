# The two set-up commands of the README: `make demo` and `make test`.
# Both create .venv when absent and install the project into it, with torch pinned by
# constraints.txt so pip never pulls a second torch or CUDA packages.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export NO_ALBUMENTATIONS_UPDATE := 1

.PHONY: install demo test lint format clean

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

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf runs .pytest_cache .ruff_cache
