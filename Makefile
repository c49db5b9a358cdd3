# `make run`: set up the virtualenv and build the default scene (workflow_config.yaml's default_scene) on the
# CPU profile; `make run SCENE=flag` builds another scene.
# `make test`: set up the virtualenv and run the test suite (what CI runs), a worker a core.
# `make test-cluster`: the Slurm executor plugin (requirements-cluster.txt) into the virtualenv, a single-node Slurm
# on this machine (tools/local_slurm.sh: root, Debian's slurm-wlm, slurmdbd, munge, mariadb-server), the workflow
# through profiles/slurm against a local run (tests/cluster), then Slurm torn down.
# `make test-gpu`: the test files that exercise CUDA (Warp's kernels, CUDA graphs, the fused Triton network, the
# exported package), whole, on a machine with a CUDA device (refused without one: skipped tests would pass).
# Setup installs the pinned requirements, then the project itself (editable), so the stages, bench/ and tests/
# import it from any directory; the stamp names both files' contents, so a change to either reinstalls.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat requirements.txt pyproject.toml | sha1sum | cut -c1-12)
SCENE ?=

CLUSTER_STAMP := $(VENV)/.cluster-$(shell cat requirements-cluster.txt | sha1sum | cut -c1-12)

GPU_TESTS := tests/sim/test_block_frame.py tests/sim/test_fem_cuda.py tests/sim/test_fem.py tests/sim/test_batched.py \
	tests/sim/test_collision.py tests/model/test_training_step.py tests/model/test_fused_network.py \
	tests/model/test_fused_features.py tests/model/test_triton_stencil.py tests/pipeline/test_inference_timing.py \
	tests/deploy/test_deploy_export.py

.PHONY: setup run test test-cluster test-gpu bench clean

setup: $(STAMP)

$(STAMP): requirements.txt pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q -e .
	rm -f $(VENV)/.installed-* && touch $@

run: $(STAMP)
	$(VENV)/bin/snakemake --cores 2 $(if $(SCENE),results/$(SCENE)/)

# One worker a core (pytest-xdist), at most 8 (a worker and the workflow builds it starts hold up to ~1 GB each),
# a test file's tests in one worker: its module fixtures, such as a workflow build of a minute, are made once.
# (The session's tiny pants build is made by each worker that has a test of it.)
test: $(STAMP)
	$(PY) -m pytest -q -n auto --maxprocesses 8 --dist loadfile tests

$(CLUSTER_STAMP): $(STAMP) requirements-cluster.txt
	$(PY) -m pip install -q -r requirements-cluster.txt
	rm -f $(VENV)/.cluster-* && touch $@

test-cluster: $(CLUSTER_STAMP)
	tools/local_slurm.sh up
	LEARNED_CLOTH_SLURM=1 SLURM_CONF=$${LOCAL_SLURM_DIR:-/tmp/local-slurm}/slurm.conf \
		$(PY) -m pytest -q tests/cluster; status=$$?; tools/local_slurm.sh down; exit $$status

test-gpu: $(STAMP)
	$(PY) -c "import sys, torch, warp; torch.cuda.is_available() and warp.is_cuda_available() or \
		sys.exit('make test-gpu: no CUDA device for torch and warp on this machine')"
	$(PY) -m pytest -q -rs $(GPU_TESTS)

bench: $(STAMP)
	$(PY) bench/cloth_solver.py

clean:
	rm -rf results .snakemake
