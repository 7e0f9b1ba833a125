"""Run a sweep on SLURM workers through dask-jobqueue (config: jobqueue.yaml beside this file).

    python slurm_sweep.py my_sweep.toml --jobs 32 --out results/sweep-big

Starts a scheduler here (the login node), submits ``--jobs`` single-worker jobs and runs
``vtol-impedance sweep`` against it (any other option is passed on); the jobs end with the script.
Interrupted (or a job killed by the queue), run the same line again: the chunks already written are kept
and only the others are flown.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import dask
import yaml
from dask_jobqueue import SLURMCluster

from vtol_impedance.cli import main


def run(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("spec", help="a sweep .toml file or a built-in study")
    p.add_argument("--jobs", type=int, default=8, help="SLURM jobs (one worker each)")
    p.add_argument("--out", default=None, help="sweep folder")
    args, rest = p.parse_known_args(argv)
    config = yaml.safe_load(Path(__file__).with_name("jobqueue.yaml").read_text())
    with dask.config.set(config), SLURMCluster() as cluster:
        cluster.scale(jobs=args.jobs)
        # queued jobs may take a while to start: wait up to an hour for the first worker
        cmd = ["sweep", args.spec, "--scheduler", cluster.scheduler_address, "--wait-workers", "3600", *rest]
        if args.out:
            cmd += ["--out", args.out]
        return main(cmd)


if __name__ == "__main__":
    sys.exit(run())
