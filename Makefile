# `make run`: set up the virtualenv and build the default scene (workflow_config.yaml's default_scene) on the
# CPU profile; `make run SCENE=flag` builds another scene.
# `make test`: set up the virtualenv and run the test suite (what CI runs).
# Setup installs the pinned requirements, then the project itself (editable), so the stages, bench/ and tests/
# import it from any directory; the stamp names both files' contents, so a change to either reinstalls.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat requirements.txt pyproject.toml | sha1sum | cut -c1-12)
SCENE ?=

.PHONY: setup run test bench clean

setup: $(STAMP)

$(STAMP): requirements.txt pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q -e .
	rm -f $(VENV)/.installed-* && touch $@

run: $(STAMP)
	$(VENV)/bin/snakemake --cores 2 $(if $(SCENE),results/$(SCENE)/)

test: $(STAMP)
	$(PY) -m pytest -q tests

bench: $(STAMP)
	$(PY) bench/cloth_solver.py

clean:
	rm -rf results .snakemake
