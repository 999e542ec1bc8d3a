# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/rgtbus solve 'abc+d' --actions open \
	    --influence 'a>b=0' --influence 'a>c=0' --influence 'a>d=0' \
	    --influence 'b>a=0' --influence 'b>c=0' --influence 'b>d=0' \
	    --influence 'c>a=0' --influence 'c>b=0' --influence 'c>d=0' \
	    --influence 'd>a=1' --influence 'd>b=1' --influence 'd>c=1'

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	$(PY) -m benchmarks

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache build *.egg-info
