#!/usr/bin/env bash
# The demo job on a real Slurm scheduler (docs/farm.md): an array of shard tasks, a merge that
# depends on them, a project per camera that depends on the merge; then a check that the merged
# buffer agrees with a single-machine run within the reported standard errors.
#
#   sudo bash scripts/slurm-demo.sh [SHARDS]          (default 4; Debian/Ubuntu, single node)
#
# Run as root on a machine without a Slurm cluster, it installs and starts one on localhost:
# Debian's slurm-wlm and munge, slurmctld and slurmd on this node. On a machine that already
# has a cluster, set SLURM_DEMO_USE_CLUSTER=1 and run it as a user: only sbatch is used.
# Not part of CI (it needs root and daemons); its last run is recorded in docs/farm.md.
set -euo pipefail

SHARDS=${1:-4}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
SENSAOV=$ROOT/.venv/bin/sensaov
PYTHON=$ROOT/.venv/bin/python
DEMO=$ROOT/out/slurm-demo
JOB=$DEMO/job.yaml

[ -x "$SENSAOV" ] || { echo "slurm-demo: run 'make setup' first" >&2; exit 3; }

start_cluster() {
    if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge >/dev/null
    fi
    if [ ! -s /etc/munge/munge.key ]; then
        mkdir -p /etc/munge && dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
        chown munge:munge /etc/munge/munge.key 2>/dev/null || true
        chmod 400 /etc/munge/munge.key
    fi
    mkdir -p /run/munge /var/log/munge /var/lib/munge
    chown -R munge:munge /run/munge /var/log/munge /var/lib/munge /etc/munge 2>/dev/null || true
    pgrep -x munged >/dev/null || runuser -u munge -- munged 2>/dev/null || munged --force
    local cpus mem host
    cpus=$(nproc)
    mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
    host=$(hostname -s)
    mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
    cat > /etc/slurm/slurm.conf <<CONF
ClusterName=sensaov-demo
SlurmctldHost=$host
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
SlurmUser=root
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
MpiDefault=none
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=demo Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
    pgrep -x slurmctld >/dev/null || slurmctld
    pgrep -x slurmd >/dev/null || slurmd
    for _ in $(seq 60); do
        sinfo -h -o %T 2>/dev/null | grep -qE '^(idle|mixed|allocated)' && return 0
        scontrol update nodename="$host" state=resume >/dev/null 2>&1 || true
        sleep 1
    done
    echo "slurm-demo: the node did not come up (see /var/log/slurm/)" >&2
    exit 3
}

if [ "${SLURM_DEMO_USE_CLUSTER:-0}" != 1 ]; then
    [ "$(id -u)" = 0 ] || { echo "slurm-demo: run as root to set up a local cluster" >&2; exit 3; }
    start_cluster
fi

# The demo job, with its outputs under out/slurm-demo (the scene stays where it is).
rm -rf "$DEMO" && mkdir -p "$DEMO/logs"
"$PYTHON" - "$ROOT/configs/cbox.yaml" "$JOB" <<'PY'
import sys
from pathlib import Path
import yaml
source, target = map(Path, sys.argv[1:])
job = yaml.safe_load(source.read_text())
job["scene"] = str((source.parent / job["scene"]).resolve())
job["output"] = str(target.parent / "out")
target.write_text(yaml.safe_dump(job, sort_keys=False))
PY
CAMERAS=$("$PYTHON" -c "from sensaov_cli.job.load import load_job; print(' '.join(c.name for c in load_job('$JOB').inspection_cameras))")
OUT=$DEMO/out
# A shared Dr.Jit kernel cache: every task after the first finds its kernels compiled.
export DRJIT_CACHE_DIR=${DRJIT_CACHE_DIR:-$DEMO/drjit-cache}

started=$(date +%s)
array=$(sbatch --parsable --job-name=sensaov-shard --array=1-"$SHARDS" --cpus-per-task=1 \
    --output="$DEMO/logs/shard-%a.log" --requeue \
    --wrap "$SENSAOV run $JOB --shard \${SLURM_ARRAY_TASK_ID}/$SHARDS --resume --progress farm")
merge=$(sbatch --parsable --job-name=sensaov-merge --dependency=afterok:"$array" \
    --output="$DEMO/logs/merge.log" \
    --wrap "$SENSAOV merge $OUT/buffer.shard-*-of-$SHARDS.npz -o $OUT/buffer.npz")
views=()
for camera in $CAMERAS; do
    views+=("$(sbatch --parsable --job-name="sensaov-$camera" --dependency=afterok:"$merge" \
        --output="$DEMO/logs/project-$camera.log" \
        --wrap "$SENSAOV project $JOB --camera $camera --png")")
done
echo "slurm-demo: submitted array $array ($SHARDS shards), merge $merge, projects ${views[*]}"

while squeue -h -j "$array,$merge,$(IFS=,; echo "${views[*]}")" 2>/dev/null | grep -q .; do
    sleep 2
done
elapsed=$(( $(date +%s) - started ))
for id in "$array" "$merge" "${views[@]}"; do
    # Finished jobs stay visible to scontrol for MinJobAge (300 s by default); an array shows
    # one line per task.
    state=$(scontrol show job "$id" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | sort | uniq -c \
        | awk '{print $2 " x" $1}' | paste -sd, || true)
    echo "slurm-demo: job $id: ${state:-gone from scontrol}"
done
[ -s "$OUT/buffer.npz" ] || { echo "slurm-demo: no merged buffer (see $DEMO/logs)" >&2; exit 1; }
for camera in $CAMERAS; do
    [ -s "$OUT/$camera.exr" ] || { echo "slurm-demo: no $camera.exr (see $DEMO/logs)" >&2; exit 1; }
done
echo "slurm-demo: scheduled work done in ${elapsed} s; grep Progress $DEMO/logs/shard-1.log:"
grep Progress "$DEMO/logs/shard-1.log" | tail -2

# The reference: one machine, the whole job at another seed, in-process batches for its errors.
"$PYTHON" - "$JOB" "$DEMO/single.yaml" "$SHARDS" <<'PY'
import sys
from pathlib import Path
import yaml
job = yaml.safe_load(Path(sys.argv[1]).read_text())
job["render"].update(seed=12345, batches=int(sys.argv[3]))
job["output"] = str(Path(sys.argv[2]).parent / "single")
Path(sys.argv[2]).write_text(yaml.safe_dump(job, sort_keys=False))
PY
"$SENSAOV" run "$DEMO/single.yaml" -q >/dev/null
"$PYTHON" "$ROOT/scripts/compare_buffers.py" "$OUT/buffer.npz" "$DEMO/single/buffer.npz"
