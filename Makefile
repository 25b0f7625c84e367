# make test / make demo work from a fresh clone: they build .venv and install the project first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: test demo bench clean

$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test,distributed,ros]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist worksteal

demo: $(STAMP)
	$(BIN)/tympani demo --out demo_out

bench: $(STAMP)
	$(BIN)/tympani bench

clean:
	rm -rf $(VENV) demo_out .pytest_cache
