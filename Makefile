# omnisonar: the two commands a newcomer needs are `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup test lint docs demo bench serve clean

setup: $(STAMP)

# Reinstall only when the project metadata changes (idempotent: a second run does nothing).
$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m pip install --quiet -e '.[peer]' || echo "pyroomacoustics could not be installed: the peer tests (tests/mapping/simulate/ism/test_peer.py) will be skipped"
	touch $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check mapping localization service tests benchmarks
	$(BIN)/mypy mapping localization service tests

# The docs site (mkdocs.yml, docs/): warnings are errors, so a broken link or docstring fails.
docs: $(STAMP)
	$(BIN)/mkdocs build --strict --site-dir site

test: lint docs
	$(BIN)/python -m pytest

demo: $(STAMP)
	$(BIN)/python -m service demo --out out/demo

bench: $(STAMP)
	@for f in benchmarks/[a-z]*.py; do m=$$(basename $$f .py); echo "== benchmarks.$$m"; $(BIN)/python -m benchmarks.$$m || exit 1; done

serve: $(STAMP)
	$(BIN)/python -m service serve

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache
