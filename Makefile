# Two commands do all the set-up on a fresh machine (see README):
#   make demo   the main job: a MuJoCo language pick-and-place episode (video, overlays, summary.json)
#   make test   the test suite
# Both create .venv and install what they need on first use.
#
# PyTorch: a bare `torch` requirement pulls several GB of CUDA wheels, so where the venv has no torch yet we
# install the CPU build first. Override for a GPU build, e.g.
#   make test TORCH_SPEC=torch TORCH_INDEX=https://download.pytorch.org/whl/cu128
# or install your own torch into .venv before the first `make`: an importable torch is never replaced.

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
TORCH_SPEC ?= torch==2.13.0
TORCH_INDEX ?=
EXTRAS ?= test,dev,sim,serve,viz,cluster,record
export MUJOCO_GL ?= egl
export HF_HUB_OFFLINE ?= 1
export TRANSFORMERS_OFFLINE ?= 1
PYTEST_ARGS ?=

.PHONY: all venv test lint demo clean help

help:
	@echo "make test    create .venv (first time) and run the test suite"
	@echo "make lint    ruff + import-linter (layer contracts) + mypy"
	@echo "make demo    the main job: a MuJoCo language pick-and-place episode into demo_out/"

all: test

$(VENV)/.installed: pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	@$(PY) -c "import torch" 2>/dev/null || { \
		echo "Installing PyTorch ($(TORCH_SPEC)) first so no CUDA wheels are pulled in"; \
		$(PY) -m pip install --quiet "$(TORCH_SPEC)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX)); }
	$(PY) -m pip install --quiet -e ".[$(EXTRAS)]"
	@touch $@

venv: $(VENV)/.installed

test: venv
	$(PY) -m pytest $(PYTEST_ARGS)

lint: venv
	$(VENV)/bin/ruff check prompose_grasp sim tests examples
	$(VENV)/bin/ruff format --check prompose_grasp sim tests examples
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy prompose_grasp

DEMO_COMMAND ?= pick up the green bottle
DEMO_OUT ?= demo_out
# more `prompose-grasp demo` flags, e.g. DEMO_ARGS="--rerun demo_out/episode.rrd" (docs/recording.md)
DEMO_ARGS ?=

demo: venv
	$(VENV)/bin/prompose-grasp demo --command "$(DEMO_COMMAND)" --out $(DEMO_OUT) --video $(DEMO_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .import_linter_cache
