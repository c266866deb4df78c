# The README's two commands: `make benchmark` (the main job) and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install test benchmark benchmark-ood docs clean

install: $(STAMP)

$(STAMP): pyproject.toml Makefile
	@echo "make: creating $(VENV) and installing gnn-mp-envs with its extras (agents, test, ompl, ray, docs, zoo);"
	@echo "      pip runs quietly (a few minutes on a fresh machine, once)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[agents,test,ompl,ray,docs,zoo]"
	touch $(STAMP)
	@echo "make: installed into $(VENV)"

test: install
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

benchmark: install
	$(BIN)/gnn-mp benchmark --suite default --out results --workers 2

# The out-of-distribution suite: every OOD scene family of every task, ratios in results/ood/ood.md.
benchmark-ood: install
	$(BIN)/gnn-mp benchmark --suite ood --out results/ood --workers 2 --no-render

# The docs site (mkdocs.yml) into site/, warnings as errors. NO_MKDOCS_2_WARNING: without it the
# Material theme prints a banner about its end of life (May 2027) on every build; not a build warning.
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) results site
