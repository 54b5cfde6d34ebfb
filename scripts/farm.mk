# A job as farm tasks, with make as the scheduler: N shard renders in parallel, one merge that
# waits for them all, then one `project` per camera in parallel. `make farm-demo` runs it on
# the demo job; docs/farm.md explains the same graph for Slurm and OpenCue/Deadline.
#
#   make -j4 -f scripts/farm.mk JOB=configs/cbox.yaml N=4 SENSAOV=.venv/bin/sensaov
#
# Every task is idempotent: a requeued shard with complete outputs made by this job is skipped
# (--resume), and make itself skips targets that are newer than their inputs.

JOB     ?= configs/cbox.yaml
N       ?= 4
SENSAOV ?= sensaov  # with PYTHON: the interpreter that has sensaov installed
PYTHON  ?= python3

# The job's output folder and inspection cameras, as sensaov reads them.
OUT     := $(shell $(PYTHON) -c "from sensaov_cli.job.load import load_job; print(load_job('$(JOB)').output)")
CAMERAS := $(shell $(PYTHON) -c "from sensaov_cli.job.load import load_job; j = load_job('$(JOB)'); print(' '.join(c.name for c in j.inspection_cameras) or 'objective')")
SHARDS  := $(foreach i,$(shell seq 1 $(N)),$(OUT)/buffer.shard-$(i)-of-$(N).npz)
VIEWS   := $(foreach c,$(CAMERAS),$(OUT)/$(c).exr)

.PHONY: all
all: $(VIEWS)

$(OUT)/buffer.shard-%-of-$(N).npz: $(JOB)
	$(SENSAOV) run $(JOB) --shard $*/$(N) --resume -q --progress farm

$(OUT)/buffer.npz: $(SHARDS)
	$(SENSAOV) merge $(SHARDS) -o $@

$(OUT)/%.exr: $(OUT)/buffer.npz
	$(SENSAOV) project $(JOB) --camera $* --png -q
