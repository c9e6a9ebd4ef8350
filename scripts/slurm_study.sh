#!/usr/bin/env bash
# Runs a study planned by `nrc compare --plan DIR` on Slurm: the jobs as job arrays (at most
# 1000 tasks each, indices 0-999, the usual MaxArraySize), each task `nrc job DIR K`, and
# the merge (`nrc compare --merge DIR`) as a job that starts once every task has succeeded.
#
#   bash scripts/slurm_study.sh DIR [sbatch options for every job, e.g. --partition=cpu --time=2:00:00]
#
# Environment: NRC, the nrc program on the compute nodes (default: `nrc` on their PATH);
# CPUS, cores per job (default 1, given to `nrc job --threads` too). The study folder and the
# scene files must be on a filesystem the nodes share, at the paths the plan was made with
# (plan.json's `cwd`): tasks start there. A task whose result exists is skipped, so the same
# command resubmits what failed.
set -euo pipefail
dir="${1:?usage: slurm_study.sh DIR [sbatch options]}"
shift
nrc="${NRC:-nrc}"
cpus="${CPUS:-1}"
plan="$dir/plan.json"
[[ -f "$plan" ]] || { echo "error: no study plan $plan (write one with nrc compare --plan $dir)" >&2; exit 1; }
read -r jobs cwd < <(python3 -c 'import json, sys; p = json.load(open(sys.argv[1])); print(len(p["jobs"]), p["cwd"])' "$plan")
abs_dir="$(cd "$dir" && pwd)"
# Array task indices stay below 1000 (MaxArraySize bounds the index, not the count): each array
# covers jobs OFFSET … OFFSET+999, the job index being NRC_OFFSET + SLURM_ARRAY_TASK_ID.
q_nrc=$(printf %q "$nrc")
q_dir=$(printf %q "$abs_dir")
ids=()
for ((first = 0; first < jobs; first += 1000)); do
  count=$(( jobs - first < 1000 ? jobs - first : 1000 ))
  id=$(sbatch --parsable "$@" --job-name=nrc-study --chdir="$cwd" --cpus-per-task="$cpus" \
    --array="0-$((count - 1))" --export="ALL,NRC_OFFSET=$first" --output="$abs_dir/jobs/slurm-%A_%a.out" \
    --wrap="$q_nrc job $q_dir \$((NRC_OFFSET + SLURM_ARRAY_TASK_ID)) --threads $cpus")
  ids+=("${id%%;*}")
done
deps=$(IFS=:; echo "${ids[*]}")
# The merge waits for every task; if one fails it is cancelled (resubmit: finished jobs are skipped).
merge=$(sbatch --parsable "$@" --job-name=nrc-study-merge --chdir="$cwd" --cpus-per-task="$cpus" \
  --dependency="afterok:$deps" --kill-on-invalid-dep=yes --output="$abs_dir/slurm-merge-%j.out" \
  --wrap="$q_nrc compare --merge $q_dir")
echo "submitted $jobs jobs as array job(s) ${ids[*]} and the merge as job ${merge%%;*}"
