#!/usr/bin/env bash
# A benchmark run split over a Slurm job array, then merged: `amstack bench --shard env/N` takes
# its shard index from SLURM_ARRAY_TASK_ID, so every array task runs the same command line.
#
#   sbatch --array=0-7 deploy/slurm/bench-array.sh                        # 8 shards
#   sbatch --dependency=afterok:<array job id> deploy/slurm/bench-array.sh merge
#
# The array must be 0-based and have exactly N tasks (--array=0-(N-1)): a shard index outside
# 0..N-1 is refused, and `bench merge` refuses a missing or duplicated shard, naming it. Rerun a
# failed shard with `sbatch --array=<i> deploy/slurm/bench-array.sh`; its part is overwritten.
#
# Needs on every node: the amstack binary at $AMSTACK and the shared folder $RUN (parts are
# written there). Edit the bench flags below; they must be identical in every shard.
#SBATCH --job-name=amstack-bench
#SBATCH --cpus-per-task=4
#SBATCH --time=02:00:00
#SBATCH --output=amstack-bench-%A_%a.out
set -euo pipefail

AMSTACK="${AMSTACK:-$HOME/amstack/target/release/amstack}"
RUN="${RUN:-$HOME/runs/fa-hexa-ikpid}"
SHARDS="${SHARDS:-8}"
BENCH_FLAGS=(--platform fa-hexa --controller ik-pid --task all --rollouts 30 --seed 0
             --disturbances reference)

if [[ "${1:-}" == "merge" ]]; then
    parts=()
    for ((i = 0; i < SHARDS; i++)); do parts+=("$RUN/parts/$i"); done
    exec "$AMSTACK" bench merge "${parts[@]}" --out "$RUN/merged"
fi

: "${SLURM_ARRAY_TASK_ID:?run this script with sbatch --array=0-$((SHARDS - 1))}"
exec "$AMSTACK" bench "${BENCH_FLAGS[@]}" --jobs "${SLURM_CPUS_PER_TASK:-1}" \
    --shard "env/$SHARDS" --out "$RUN/parts/$SLURM_ARRAY_TASK_ID"
