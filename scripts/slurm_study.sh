#!/usr/bin/env bash
# Runs a study planned by `nrc compare --plan DIR` on Slurm: the jobs as job arrays (at most
# 1000 tasks each, the usual MaxArraySize), each task `nrc job DIR $SLURM_ARRAY_TASK_ID`, and
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
ids=()
for ((first = 0; first < jobs; first += 1000)); do
  last=$(( first + 999 < jobs - 1 ? first + 999 : jobs - 1 ))
  id=$(sbatch --parsable "$@" --job-name=nrc-study --chdir="$cwd" --cpus-per-task="$cpus" \
    --array="$first-$last" --output="$abs_dir/jobs/slurm-%A_%a.out" \
    --wrap="$nrc job $abs_dir \$SLURM_ARRAY_TASK_ID --threads $cpus")
  ids+=("${id%%;*}")
done
deps=$(IFS=:; echo "${ids[*]}")
merge=$(sbatch --parsable "$@" --job-name=nrc-study-merge --chdir="$cwd" --cpus-per-task="$cpus" \
  --dependency="afterok:$deps" --output="$abs_dir/slurm-merge-%j.out" \
  --wrap="$nrc compare --merge $abs_dir")
echo "submitted $jobs jobs as array job(s) ${ids[*]} and the merge as job ${merge%%;*}"
