# `make demo`, `make test`, `make bench`: each creates .venv and installs endopipe when missing.
VENV ?= .venv
PY := $(VENV)/bin/python
# The CPU build of torch comes first: a bare `torch` requirement would pull multi-GB CUDA wheels.
# GPU users: make TORCH_SPEC='torch' (or the build for their CUDA) ...
TORCH_SPEC ?= torch==2.13.0
STAMP := $(VENV)/.installed
#: The repository folders setup.py installs as endopipe.<folder> (its LAYERS).
LAYERS := pipeline stages jobs recording synth export

.PHONY: demo test imports bench lint format clean-venv

$(STAMP): pyproject.toml setup.py
	bash scripts/system-deps.sh
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "$(TORCH_SPEC)"
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/endopipe demo

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(MAKE) --no-print-directory imports
	$(VENV)/bin/pytest

# The import contracts of pyproject.toml. grimp walks the package's folder, and the repository keeps
# its layers (pipeline/, stages/, ...) beside endopipe/, so lint-imports reads a symlink tree with
# the installed layout (endopipe/pipeline -> pipeline/, ...), from outside the repository.
imports: $(STAMP)
	@tree=$$(mktemp -d) && trap 'rm -rf "$$tree"' EXIT && mkdir "$$tree/endopipe" && \
	ln -s "$(CURDIR)"/endopipe/* $(addprefix "$(CURDIR)"/,$(LAYERS)) "$$tree/endopipe/" && \
	cd "$$tree" && PYTHONPATH="$$tree" "$(CURDIR)/$(VENV)/bin/lint-imports" \
		--config "$(CURDIR)/pyproject.toml" --no-cache

bench: $(STAMP)
	$(VENV)/bin/endopipe bench

format: $(STAMP)
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

clean-venv:
	rm -rf $(VENV)
