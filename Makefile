# Every target creates or refreshes the virtual environment in .venv first (idempotent).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: venv test demo bench clean

venv: $(STAMP)

# Reinstalled only when the requirements or setup files change.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements-dev.txt
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

test: venv
	$(BIN)/python -m pytest -q test

demo: venv
	$(BIN)/pearl_segment_bag bags/*/

bench: venv
	$(BIN)/pearl_bench hopkins155 ../shared/data/hopkins155 --frames all

clean:
	rm -rf $(VENV) build *.egg-info
