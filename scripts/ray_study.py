#!/usr/bin/env python3
"""Runs a study planned by `nrc compare --plan DIR` on Ray, then merges it.

Each job is a Ray task (one CPU by default) that runs `nrc job DIR K` and returns the result
file's bytes, which the driver writes into DIR/jobs (atomically), so a worker needs no shared
filesystem to report back. Reference chunks are submitted first, then the method runs; failed
tasks are retried; a job whose result exists is not submitted again, so rerunning the command
resumes a study. Then `nrc compare --merge DIR` writes the report.

    python3 scripts/ray_study.py DIR [--nrc PATH] [--address ADDRESS] [--cpus-per-job N]

Locally (a laptop): no --address; Ray starts a local cluster (--num-cpus to size it). On a
cluster: --address auto (or ray://HEAD:10001). The workers need the nrc program and the scene
files: either on a shared filesystem at the same paths (the plan's `cwd`, the default), or
shipped with the job as Ray's runtime environment: --ship DIR uploads DIR (holding the program,
the scenes and the study folder, at the relative paths the plan names) as the tasks' working
directory.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dir", help="the study folder (nrc compare --plan DIR)")
    p.add_argument("--nrc", default=os.environ.get("NRC", "nrc"), help="the nrc program on the workers")
    p.add_argument("--address", default=None, help="a Ray cluster (default: start a local one)")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local cluster")
    p.add_argument("--cpus-per-job", type=int, default=1)
    p.add_argument("--retries", type=int, default=2, help="retries of a failed task")
    p.add_argument("--ship", default=None, help="upload this folder as the tasks' working directory")
    p.add_argument("--no-merge", action="store_true", help="run the jobs only")
    return p.parse_args(argv)


def write_atomic(path, data):
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix="." + os.path.basename(path) + ".")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    import ray

    study = os.path.abspath(args.dir)
    plan_path = os.path.join(study, "plan.json")
    if not os.path.exists(plan_path):
        print(f"error: no study plan {plan_path} (write one with nrc compare --plan DIR)", file=sys.stderr)
        return 1
    with open(plan_path) as f:
        plan = json.load(f)
    if not args.no_merge and not os.path.isdir(plan["cwd"]):
        print(f"error: the merge runs in the plan's folder {plan['cwd']}, which this machine lacks", file=sys.stderr)
        return 1
    if args.ship:
        ship = os.path.abspath(args.ship)
        study_on_worker = os.path.relpath(study, ship)
        if study_on_worker.startswith(".."):
            print(f"error: the study folder {study} is not inside the shipped folder {ship}", file=sys.stderr)
            return 1
        if os.path.abspath(plan["cwd"]) != ship:
            print(f"error: --ship must be the folder the study was planned in ({plan['cwd']}): its paths are relative to it", file=sys.stderr)
            return 1
        # Ray's upload leaves out what .gitignore names (target/, out/): ship a folder holding
        # the program, the scenes and the study outside ignored paths.
        ray.init(address=args.address, runtime_env={"working_dir": ship})
        cwd = None
    else:
        ray.init(address=args.address, num_cpus=args.num_cpus if args.address is None else None)
        cwd, study_on_worker = plan["cwd"], study

    @ray.remote(num_cpus=args.cpus_per_job, max_retries=args.retries, retry_exceptions=True)
    def run_job(k, output):
        start = time.time()
        done = subprocess.run(
            [args.nrc, "job", study_on_worker, str(k), "--threads", str(args.cpus_per_job)],
            cwd=cwd, capture_output=True, text=True,
        )
        if done.returncode != 0:
            raise RuntimeError(f"job {k}: {done.stderr.strip() or done.stdout.strip()}")
        with open(os.path.join(cwd or ".", study_on_worker, output), "rb") as f:
            return k, f.read(), time.time() - start

    # Reference chunks first, then the methods' runs; jobs with a result are done already.
    jobs = sorted(plan["jobs"], key=lambda j: j["kind"] != "reference-chunk")
    todo = [j for j in jobs if not os.path.exists(os.path.join(study, j["output"]))]
    print(f"ray: {len(todo)} of {len(jobs)} jobs to run on {ray.cluster_resources().get('CPU', 0):.0f} CPUs", flush=True)
    outputs = {j["id"]: j["output"] for j in jobs}
    pending = [run_job.remote(j["id"], j["output"]) for j in todo]
    failed = []
    finished = 0
    start = time.time()
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        try:
            k, data, seconds = ray.get(ready[0])
        except Exception as e:  # after the retries
            failed.append(str(e).strip().splitlines()[-1])
            continue
        write_atomic(os.path.join(study, outputs[k]), data)
        finished += 1
        print(f"ray: job {k} done in {seconds:.1f} s ({finished}/{len(todo)}, {time.time() - start:.0f} s)", flush=True)
    ray.shutdown()
    if failed:
        print(f"error: {len(failed)} job(s) failed: {'; '.join(failed)}", file=sys.stderr)
        return 1
    if args.no_merge:
        return 0
    merged = subprocess.run([args.nrc, "compare", "--merge", study], cwd=plan["cwd"])
    return merged.returncode


if __name__ == "__main__":
    sys.exit(main())
