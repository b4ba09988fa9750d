# make demo / make test: set up .venv (and the system EGL libraries if missing), then run.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.glsim-installed
EGL_PKGS := libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1
X11_PKGS := xvfb xdotool x11-apps chromium glslang-tools

.PHONY: demo test test-fast test-gl test-engine test-torch test-tools bench venv egl x11 clean readme-check

demo: venv
	$(BIN)/glsim demo

# two pytest workers: many tests wait on subprocesses, servers or a browser, so two overlap well
# even on two cores
test: venv x11 readme-check
	$(BIN)/python -m pytest -q -ra -n 2 --durations=25 -m "not engine and not tools"
	# the GL tier again in the pixel stage a GPU gets (llvmpipe's own is fragment): the renders'
	# own tests; the workflows built on them, and the tests that set the stage themselves, ran in
	# the first pass
	GLSIM_PIXEL_STAGE=compute $(BIN)/python -m pytest -q -ra -n 2 -m "gl and not workflow and not both_stages"

# the loop while changing code: every in-process test (GL included), none that starts another
# process (library worker pools, CLI subprocesses, forked checks, Xvfb, a browser, a cluster)
# and none that runs a whole command end to end (slow); make test runs them all
test-fast: venv
	$(BIN)/python -m pytest -q -ra -n 2 -m "not process and not slow and not tools"

# the developer tools' own tests: the benchmarks' reduced runs and the docs' code blocks (CI runs
# them after make test, .ci/run; make test keeps to the product)
test-tools: venv x11
	$(BIN)/python -m pytest -q -ra -n 2 -m tools

# every measured figure in README.md and docs/ equals what its bench/results file gives
readme-check: venv
	$(BIN)/python -m tools.docs --check

test-gl: venv
	$(BIN)/python -m pytest -q -m gl

bench: venv
	$(BIN)/glsim bench accuracy

venv: egl $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

# An EGL implementation (Mesa llvmpipe where there is no GPU) must be present for backend="gl".
egl:
	@if ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0\|libEGL_nvidia.so.0'; then \
	  echo "EGL: found"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "EGL: missing, installing $(EGL_PKGS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(EGL_PKGS); \
	else \
	  echo "EGL: no EGL implementation found; install: sudo apt-get install $(EGL_PKGS)"; \
	  echo "     (backend='cpu' works without it; GL tests will fail)"; \
	fi

# The preview window's test runs under a virtual X server it starts itself (Xvfb), sends real
# key and mouse events (xdotool) and reads the window back (xwd); the notebook widget's test runs
# JupyterLab in headless Chromium; the float64-path audit reads glslangValidator's intermediate
# tree (tests/test_fp64_path.py). Without them those tests are skipped.
x11:
	@if command -v Xvfb >/dev/null && command -v xdotool >/dev/null && command -v xwd >/dev/null && command -v chromium >/dev/null && command -v glslangValidator >/dev/null; then \
	  echo "Xvfb: found"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "Xvfb: missing, installing $(X11_PKGS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(X11_PKGS); \
	else \
	  echo "Xvfb: not found; install: sudo apt-get install $(X11_PKGS) (the preview window test is skipped)"; \
	fi

clean:
	rm -rf $(VENV) build dist *.egg-info glsim-demo

# make verify: glsim's bulge images measured by an independent stereo DIC (pyvale, in its own
# .venv-verify of about 2 GB), compared with the imposed coordinates → bench/results/verify.*
VERIFY_VENV  := .venv-verify
VERIFY_STAMP := $(VERIFY_VENV)/.pyvale-installed

.PHONY: verify sweep

verify: venv $(VERIFY_STAMP)
	$(BIN)/glsim verify run

# make sweep: rigid-body sweep 0…1 px measured by pyvale's 2-D DIC (verify/dic2d.py, same
# .venv-verify) → bench/results/sweep.{json,md,png} and frontier.png (from accuracy.json)
sweep: venv $(VERIFY_STAMP)
	$(BIN)/glsim verify sweep

# make test-engine: the tests that run the real DIC engine (glsim design with pyvale, 2-D and
# stereo, on tiny cases), after making its environment; a skip there is a failure. CI runs it
# after make test (.ci/run); make test itself stays without the 2 GB environment.
test-engine: venv $(VERIFY_STAMP)
	GLSIM_REQUIRE_ENGINE=1 $(BIN)/python -m pytest -q -ra -n 2 -m engine

$(VERIFY_STAMP): verify/requirements.txt
	test -x $(VERIFY_VENV)/bin/python || $(PYTHON) -m venv $(VERIFY_VENV)
	$(VERIFY_VENV)/bin/python -m pip install -q --upgrade pip
	$(VERIFY_VENV)/bin/python -m pip install -q -r verify/requirements.txt
	touch $@

# make test-torch: the PyTorch loader's tests (examples/training_loader.py: pytest -m torch and
# docs/training.md's blocks), after installing torch into .venv where it is not importable (the CPU
# build, 2.13.0: 25 s and 0.9 GB here from a local wheel; the tests need glsim, GL and the test
# tools, which .venv has); a skip there is a failure. Without a local CPU wheel PyPI gives the CUDA
# build: make test-torch TORCH="torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"
TORCH ?= torch==2.13.0
test-torch: venv
	$(BIN)/python -c "import torch" 2>/dev/null || $(BIN)/python -m pip install -q $(TORCH)
	GLSIM_REQUIRE_TORCH=1 $(BIN)/python -m pytest -q -ra -m torch
	$(BIN)/python -m pytest -q -ra tests/test_doc_examples.py -k "test_every_block_runs and docs/training.md"
