# labctl: the two commands of the README's Quick start.
#   make demo  - simulated characterization of the four cameras, their reports and their comparison, then a check
#                of the files it wrote (tests/check_demo.py: keyfigures.json against its schema, the blaze-101's PDF)
#   make test  - the linter (ruff), then the whole test suite
# Both create (or refresh, when pyproject.toml changed) the virtual environment .venv, then check that
# every native SDK imports (labctl/setup_check.py): as root a missing system library is installed with
# apt-get (and so is the optional test tool strace), otherwise the set-up stops with the command to run. No root is needed on Debian/Ubuntu: the
# one system library (libusb-1.0, for pyrealsense2) comes from the libusb-package wheel.

PYTHON ?= $(shell for p in python3.11 python3.12 python3; do \
	  command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(not ((3, 11) <= sys.version_info[:2] < (3, 13)))' 2>/dev/null \
	  && { command -v $$p; break; }; done)
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_DIR ?= demo-output
DEMO_CAMERAS ?= blaze101 amt100 flexx2 d455
PYTEST_WORKERS ?= 2

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@if [ -z "$(PYTHON)" ]; then echo "labctl needs Python 3.11 or 3.12 (none found on PATH)"; exit 1; fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m labctl.setup_check --install
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadgroup

demo: $(STAMP)
	@rm -rf $(DEMO_DIR) && mkdir -p $(DEMO_DIR)
	@for camera in $(DEMO_CAMERAS); do \
	  echo "== $$camera: simulated characterization (examples/demo/$$camera.toml)"; \
	  $(BIN)/labctl plan examples/demo/$$camera.toml | grep "^campaign" && \
	  $(BIN)/labctl run examples/demo/$$camera.toml --sim -o $(DEMO_DIR)/$$camera.h5 && \
	  $(BIN)/labctl evaluate $(DEMO_DIR)/$$camera.h5 -o $(DEMO_DIR)/$$camera || exit 1; \
	done
	$(BIN)/labctl compare $(addprefix $(DEMO_DIR)/,$(DEMO_CAMERAS)) -o $(DEMO_DIR)/comparison
	$(BIN)/python -m tests.check_demo $(DEMO_DIR) $(DEMO_CAMERAS)
	@echo "Open the reports: $(abspath $(DEMO_DIR))/<camera>/report.html and $(abspath $(DEMO_DIR))/comparison/compare.html"

bench: $(STAMP)
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) $(DEMO_DIR) .pytest_cache
