# Two commands work on a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo_out

.PHONY: demo test lint bench clean venv

venv: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# one OpenCV build (contrib); an older .venv with the plain build gets it replaced
	if $(BIN)/python -m pip show -q opencv-python-headless 2>/dev/null; then \
	  $(BIN)/python -m pip uninstall -y -q opencv-python-headless opencv-contrib-python-headless; fi
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev,all]'
	touch $@

test: venv
	$(BIN)/python -m pytest -q -n 2 blurtrack rigs calib gamd tests

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

demo: venv
	rm -rf $(DEMO_OUT)
	$(BIN)/blurtrack demo --out $(DEMO_OUT)

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache build *.egg-info
