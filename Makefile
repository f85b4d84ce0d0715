# labctl: the two commands of the README's Quick start.
#   make demo  - simulated characterization campaign, evaluation and HTML report
#   make test  - the whole test suite
# Both create (or refresh, when pyproject.toml changed) the virtual environment .venv.

PYTHON ?= $(shell for p in python3.11 python3.12 python3; do \
	  command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(not ((3, 11) <= sys.version_info[:2] < (3, 13)))' 2>/dev/null \
	  && { command -v $$p; break; }; done)
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_DIR ?= demo-output
PYTEST_WORKERS ?= 2

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@if [ -z "$(PYTHON)" ]; then echo "labctl needs Python 3.11 or 3.12 (none found on PATH)"; exit 1; fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS)

demo: $(STAMP)
	@rm -rf $(DEMO_DIR) && mkdir -p $(DEMO_DIR)
	$(BIN)/labctl plan examples/demo_blaze101.toml
	$(BIN)/labctl run examples/demo_blaze101.toml --sim -o $(DEMO_DIR)/blaze101.h5
	$(BIN)/labctl evaluate $(DEMO_DIR)/blaze101.h5 -o $(DEMO_DIR)/blaze101
	@echo "Open the report: $(abspath $(DEMO_DIR))/blaze101/report.html"

bench: $(STAMP)
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) $(DEMO_DIR) .pytest_cache
