#!/usr/bin/env python3
"""Train the segments of a tadgs plan as Ray tasks, then merge them.

    tadgs segment plan scenes/panoptic.ron --segments 3 -o plans/panoptic
    python scripts/ray_segments.py plans/panoptic --cpus-per-segment 8

Ray places, runs and retries the tasks (on the cluster of `--address`, or a local one
started for the run); each task runs `tadgs segment train PLAN --segment K` on a machine that
sees the plan folder, which trains the segment, resumes it from its checkpoint when Ray
retries it, or does nothing when it is trained already. Once every task succeeded the
driver runs `tadgs segment merge`. Nothing here schedules, retries or talks to other
machines itself.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys

import ray


def segment_count(plan_dir):
    """Number of segments in DIR/plan.ron (one `run:` field per segment)."""
    path = os.path.join(plan_dir, "plan.ron")
    with open(path, encoding="utf-8") as f:
        runs = re.findall(r'\brun:\s*"', f.read())
    if not runs:
        sys.exit(f"{path} names no segment: write it with `tadgs segment plan`")
    return len(runs)


@ray.remote
def train_segment(tadgs, plan_dir, index, threads):
    """Runs `tadgs segment train` for one segment; raises with its error output on failure."""
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    command = [tadgs, "-q", "segment", "train", plan_dir, "--segment", str(index)]
    result = subprocess.run(command, env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"segment {index}: {' '.join(command)} failed:\n{result.stderr[-4000:]}")
    return f"segment {index}: {result.stdout.strip().splitlines()[-1] if result.stdout.strip() else 'trained'}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("plan", help="the plan folder written by `tadgs segment plan`")
    parser.add_argument("--tadgs", default=os.environ.get("TADGS") or shutil.which("tadgs"),
                        help="path of the tadgs binary on every node (default: $TADGS or PATH)")
    parser.add_argument("--cpus-per-segment", type=int, default=1,
                        help="CPUs Ray reserves for each segment's task (its training threads)")
    parser.add_argument("--retries", type=int, default=2,
                        help="how often Ray reruns a failed task (it resumes from its checkpoint)")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (default: start a local one)")
    args = parser.parse_args()
    if not args.tadgs:
        sys.exit("no tadgs binary: put it on PATH, set TADGS or pass --tadgs")
    tadgs = os.path.abspath(args.tadgs)
    plan_dir = os.path.abspath(args.plan)
    count = segment_count(plan_dir)

    ray.init(address=args.address, include_dashboard=False, log_to_driver=False)
    task = train_segment.options(num_cpus=args.cpus_per_segment, max_retries=args.retries,
                                 retry_exceptions=True)
    pending = [task.remote(tadgs, plan_dir, k, args.cpus_per_segment) for k in range(count)]
    try:
        for message in ray.get(pending):
            print(message, flush=True)
    except ray.exceptions.RayTaskError as error:
        sys.exit(f"a segment failed after {args.retries} retries: {error.cause}")
    finally:
        ray.shutdown()
    subprocess.run([tadgs, "segment", "merge", plan_dir, "--force"], check=True)


if __name__ == "__main__":
    main()
