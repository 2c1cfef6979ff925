#!/usr/bin/env bash
# `stablemo fit` on a SLURM cluster: 4 nodes x 8 GPUs, one task per GPU; Lightning reads the task's
# rank from SLURM_PROCID / SLURM_NODEID / SLURM_LOCALID and node 0's address from SLURM_NODELIST.
#
#   sbatch scripts/cluster/sbatch_fit.sh --config configs/synth_small.yaml --trainer.accelerator=gpu
#
# Arguments go to `stablemo fit`. `--ckpt_path last` makes the job resumable as it is: the first run
# starts from scratch, a requeued or resubmitted one continues exactly from the run folder's last.ckpt
# (trainer.default_root_dir must be on a filesystem all nodes share). tests/test_multinode.py runs
# this file with a stand-in `srun` that starts 2 tasks on 127.0.0.1 (gloo) with the variables srun sets.
#SBATCH --job-name=stablemo
#SBATCH --nodes=4
#SBATCH --ntasks-per-node=8
#SBATCH --gpus-per-node=8
#SBATCH --cpus-per-task=8
#SBATCH --time=24:00:00
#SBATCH --signal=SIGUSR1@120
#SBATCH --requeue
#SBATCH --output=%x-%j.out
set -euo pipefail
PYTHON=${PYTHON:-python}
# SIGUSR1 two minutes before the time limit: Lightning saves a checkpoint and requeues the job
# the layout flags come last: they win over a config's trainer.num_nodes/devices (Lightning checks them
# against the allocation)
srun "$PYTHON" -m stablemo.cli fit --ckpt_path last "$@" --trainer.num_nodes "$SLURM_NNODES" --trainer.devices "$SLURM_NTASKS_PER_NODE"
