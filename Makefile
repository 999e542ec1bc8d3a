# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test docs lint typecheck imports tree bench clean bytecode

$(STAMP): pyproject.toml setup.py MANIFEST.in rgtbus/signal/_walk.pyx
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: $(STAMP) bytecode
	$(VENV)/bin/rgtbus run scenarios/gate.toml --check

test: $(STAMP) bytecode
	$(VENV)/bin/ruff check .
	$(MAKE) --no-print-directory typecheck
	$(MAKE) --no-print-directory imports
	$(PY) -m pytest -q

# Byte-compile the tree (only what changed): a shell that sets PYTHONDONTWRITEBYTECODE would
# otherwise compile every module at every start of a command (docs/engine.md, "Measured").
bytecode: $(STAMP)
	@$(PY) -m compileall -q -j 0 rgtbus units scenarios benchmarks > /dev/null

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# The type checker and the import contracts read the package as it installs (units/ is
# rgtbus.units): a tree of links to the sources, made anew.
tree: $(STAMP)
	@rm -rf build/tree && mkdir -p build/tree
	@cp -rs $(CURDIR)/rgtbus build/tree/rgtbus && cp -rs $(CURDIR)/units build/tree/rgtbus/units
	@find build/tree -name __pycache__ -prune -exec rm -rf {} +

# The whole package is held to mypy --strict.
typecheck: tree
	cd build/tree && $(CURDIR)/$(VENV)/bin/mypy --config-file $(CURDIR)/pyproject.toml --strict -p rgtbus

# The layering and the parts' independence, as contracts ([tool.importlinter] in pyproject.toml).
imports: tree
	cd build/tree && PYTHONPATH=. $(CURDIR)/$(VENV)/bin/lint-imports --no-logo --no-cache \
		$(CURDIR)/pyproject.toml

# The documentation site (mkdocs-material, mkdocstrings), strict: a broken link, a missing
# reference or a failing notebook cell fails it. Into site/.
DOCS_STAMP := $(VENV)/.docs-installed
$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[docs]'
	@touch $(DOCS_STAMP)

docs: $(DOCS_STAMP) tree
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

bench: $(STAMP)
	$(PY) -m benchmarks

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache build *.egg-info site
