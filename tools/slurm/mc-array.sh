#!/usr/bin/env bash
# One shard of an `ianav-sim mc` batch per Slurm array task, every task writing into one
# shared output directory (tools/slurm/README.md, docs/MONTECARLO.md "Slurm").
#
#   sbatch --array=1-N [sbatch options] mc-array.sh N OUT MC_OPTIONS...
#
# N: the number of shards, given here rather than read from the array, so that resubmitting
# some tasks (--array=2,5) flies the same shards. OUT: the shared output directory.
# MC_OPTIONS: the batch (--scenario, --runs or --seeds, --duration, --terrain, ...), the same
# for every task and every resubmission; not --shard, --jobs, --resume or --out, which this
# script sets. Every task runs with --resume: a resubmitted task keeps the whole runs already
# in OUT and flies only the missing ones. The binary is $IANAV_SIM (default: ianav-sim on the
# PATH); the worker threads are the task's CPUs (--cpus-per-task).
#SBATCH --job-name=ianav-mc
#SBATCH --cpus-per-task=1
set -euo pipefail

usage() {
  echo "usage: sbatch --array=1-N [sbatch options] $0 N OUT MC_OPTIONS..." >&2
  exit 2
}
[ $# -ge 2 ] || usage
shards=$1
out=$2
shift 2
task=${SLURM_ARRAY_TASK_ID:-}
if [ -z "$task" ]; then
  echo "mc-array: not a Slurm array task (submit with sbatch --array=1-$shards)" >&2
  exit 2
fi
if ! [[ $shards =~ ^[1-9][0-9]*$ ]] || [ "$task" -lt 1 ] || [ "$task" -gt "$shards" ]; then
  echo "mc-array: array index $task is not a shard of 1..$shards (N = '$shards')" >&2
  exit 2
fi
for arg in "$@"; do
  case $arg in
    --shard|--shard=*|--jobs|--jobs=*|--resume|--out|--out=*)
      echo "mc-array: $arg is set by this script; leave it out of MC_OPTIONS" >&2
      exit 2 ;;
  esac
done
sim=${IANAV_SIM:-ianav-sim}
jobs=${SLURM_CPUS_PER_TASK:-1}
mkdir -p "$out"
echo "mc-array: job ${SLURM_ARRAY_JOB_ID:-?}_$task (id ${SLURM_JOB_ID:-?}) on $(hostname)," \
  "$(date -u +%Y-%m-%dT%H:%M:%SZ): shard $task/$shards, jobs $jobs, out $out"
echo "mc-array: $sim mc $* --shard $task/$shards --jobs $jobs --resume --out $out"
status=0
"$sim" mc "$@" --shard "$task/$shards" --jobs "$jobs" --resume --out "$out" || status=$?
echo "mc-array: shard $task/$shards ended with status $status at $(date -u +%Y-%m-%dT%H:%M:%SZ)"
exit "$status"
