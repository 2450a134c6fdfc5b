# Two commands set everything up on a fresh machine: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# One thread everywhere: speed is measured single-threaded, and tests share a 2-core machine.
export OMP_NUM_THREADS := 1
export OPENBLAS_NUM_THREADS := 1
export MKL_NUM_THREADS := 1
export MAVLINK20 := 1

.PHONY: run test eval longterm bench clean

# The compiled feature kernels are rebuilt when their source changes.
$(STAMP): pyproject.toml jsar/features/_kernels.c
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,gcs]'
	touch $(STAMP)

run: $(STAMP)
	$(PY) -m sim.demo

test: $(STAMP)
	$(PY) -m pytest -q -rs  # -rs: say why tests were skipped (e.g. no JSAR_DATA_ROOT)

# Research: the tracker on the shared real sequences (DATA defaults to the shared data beside the repo).
DATA ?= ../shared/data/uav
eval: $(STAMP)
	$(PY) -m jsar.eval $(DATA) --trackers jsar-re,jsar,strcf,csrt,kcf --published $(dir $(DATA))published --json out/eval.json --plots out/plots

longterm: $(STAMP)
	$(PY) -m jsar.eval $(DATA) --longterm --trackers jsar-re,jsar,csrt --json out/longterm.json

bench: $(STAMP)
	$(PY) -m bench.tracking $(DATA) --trackers jsar,csrt
	JSAR_DATA_ROOT=$(DATA) $(PY) -m bench.service

clean:
	rm -rf $(VENV) out
