#!/usr/bin/env bash
# One task of a tgs job array: trains the dataset on line $SLURM_ARRAY_TASK_ID
# (0-based; blank lines and lines starting with # do not count) of
# DATASETS into OUT_ROOT/<the dataset's directory name>, and picks the run
# up where it stopped when the scheduler runs the task again.
#
#   train-task.sh DATASETS OUT_ROOT [tgs train options for a new run...]
#
# - A new run: `tgs train DATASET --out OUT OPTIONS...`.
# - OUT/checkpoint.bin present (the task was pre-empted or hit its time
#   limit and was requeued): `tgs train --resume --out OUT`, with the run's
#   saved settings (the options are not passed again); a finished run is
#   reported and left as it is.
# - SIGTERM or SIGINT (what SLURM sends before the time limit with
#   `--signal=B:TERM@SECONDS`, or on pre-emption) is passed on to tgs, which
#   finishes its iteration and writes a checkpoint; then, under SLURM, the
#   task requeues itself (`scontrol requeue`) and exits 0. Elsewhere it exits
#   130, and running it again resumes.
#
# Environment: TGS (the tgs binary; default `tgs` on PATH), TGS_DEVICE (the
# Vulkan device, as for tgs). Exit status: tgs's (0 done, 130 interrupted,
# 1 an error, with tgs's message on stderr).
set -uo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 DATASETS OUT_ROOT [tgs train options...]" >&2
  exit 2
fi
list=$1
root=$2
shift 2
tgs=${TGS:-tgs}
task=${SLURM_ARRAY_TASK_ID:-}
if [ -z "$task" ]; then
  echo "$0: SLURM_ARRAY_TASK_ID is not set (submit with sbatch --array, or set it to the line to train)" >&2
  exit 2
fi
if [ ! -r "$list" ]; then
  echo "$0: cannot read the dataset list $list" >&2
  exit 2
fi
dataset=$(grep -v -e '^[[:space:]]*#' -e '^[[:space:]]*$' "$list" | sed -n "$((task + 1))p")
if [ -z "$dataset" ]; then
  echo "$0: $list has no dataset for array task $task (lines are counted from 0)" >&2
  exit 2
fi
out="$root/$(basename "$dataset")"
mkdir -p "$root"

if [ -f "$out/checkpoint.bin" ]; then
  echo "task $task: resuming $out"
  cmd=("$tgs" train --resume --out "$out")
else
  echo "task $task: training $dataset into $out"
  cmd=("$tgs" train "$dataset" --out "$out" "$@")
fi

# tgs runs in the background so that this shell can take the signal and
# pass it on (bash runs a trap only between commands; `wait` returns early).
stopping=0
forward() {
  stopping=1
  kill -TERM "$pid" 2>/dev/null
}
trap forward TERM INT
"${cmd[@]}" &
pid=$!
status=0
while :; do
  wait "$pid"
  status=$?
  # A trap ends `wait` early with a status above 128 while tgs runs on.
  if kill -0 "$pid" 2>/dev/null; then
    continue
  fi
  break
done
trap - TERM INT

if [ "$status" -eq 130 ] || [ "$stopping" -eq 1 ]; then
  if [ -n "${SLURM_JOB_ID:-}" ] && command -v scontrol >/dev/null 2>&1; then
    job=${SLURM_ARRAY_JOB_ID:+${SLURM_ARRAY_JOB_ID}_${task}}
    job=${job:-$SLURM_JOB_ID}
    echo "task $task: interrupted (tgs exit $status); requeueing $job to resume"
    scontrol requeue "$job"
    exit 0
  fi
  echo "task $task: interrupted (tgs exit $status); run this task again to resume"
  exit 130
fi
exit "$status"
