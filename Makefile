# FluidGaussian: two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test test-quick bench gpu-check lint clean

venv: $(STAMP)

# torch first: torch==2.13.0 resolves to the CPU wheel already on disk; an unpinned torch
# would pull several GB of CUDA builds.
$(STAMP): setup.cfg
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e .[test,view,ray]
	@# open3d's wheel needs libusb and libgomp from the system; install them when missing (root + apt).
	$(PY) -c "import open3d" 2>/dev/null || { command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ] && \
	  apt-get update -qq && apt-get install -y -qq libusb-1.0-0 libgomp1 libgl1 >/dev/null; }
	$(PY) -c "import open3d, taichi, torch, h5py, cv2, viser, ray"
	touch $(STAMP)

demo: venv
	$(VENV)/bin/fluidgs demo -o out/demo

test: venv lint
	$(PY) -m pytest -q -p no:dash tests

# The engine, the splat readers and the CLI smoke tests, with ruff check: under 2 min on 2 cores (72 s measured with
# other work running), against about 8 min for `make test` on a quiet 2-core machine.
QUICK_TESTS := tests/fluidsim tests/recon/test_formats.py tests/recon/test_readers.py tests/apps/test_cli_smoke.py
test-quick: venv
	$(VENV)/bin/ruff check fluidsim recon nbv apps viz tests
	$(PY) -m pytest -q -p no:dash $(QUICK_TESTS)

bench: venv
	$(VENV)/bin/fluidgs bench sim

# The CUDA checks (docs/testing.md), prepared for a lent GPU machine whose time is short: stop at once when Taichi
# finds no CUDA device, then the Taichi tests (fluidsim, nbv) on CUDA, and the engine and the probes at the paper
# setting timed on the device.
# Each step is bounded (about 9 minutes in all); the figures land in out/gpu-check/.
gpu-check: venv
	$(PY) -c "import taichi as ti; ti.init(arch=ti.cuda, log_level=ti.ERROR); \
	  a = ti.lang.impl.current_cfg().arch; assert a == ti.cuda, f'no CUDA device: Taichi started on {a}'"
	mkdir -p out/gpu-check
	-FLUIDGS_TEST_ARCH=cuda timeout 300 $(PY) -m pytest -q -p no:dash tests/fluidsim tests/nbv 2>&1 | tail -n 30
	timeout 90 $(VENV)/bin/fluidgs bench sim --device cuda --no-peer --json out/gpu-check/sim.json
	timeout 150 $(VENV)/bin/fluidgs bench score --device cuda --paper --json out/gpu-check/score.json

lint: venv
	$(VENV)/bin/ruff check fluidsim recon nbv apps viz tests
	$(VENV)/bin/ruff format --check fluidsim recon nbv apps viz tests

clean:
	rm -rf out .pytest_cache
