"""Multi-node training proven on one machine: 2 "nodes" x 1 process on 127.0.0.1 with gloo, launched
through the cluster entry points users run (scripts/cluster/torchrun_node.sh, the srun line of
scripts/cluster/sbatch_fit.sh under the variables srun sets), against 1 node x 2 processes
(Lightning's own launcher) on the same global batch; and a hard kill on either node, resumed by
restarting both nodes with `--ckpt_path last`, against the uninterrupted run. Each with the folder
reader and streaming from `stablemo data shard` shards; and the model fully sharded (FSDP) over the
2 torchrun nodes, streaming shards, against the same on 1 node.

Each run is a set of fresh processes (~10-30 s apiece on 2 busy cores): the tests are marked slow
and .ci/run runs them.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from test_training import tiny_config

from stablemo.training.checkpoint_io import load_checkpoint_file

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
TORCHRUN = REPO / "scripts" / "cluster" / "torchrun_node.sh"
SBATCH = REPO / "scripts" / "cluster" / "sbatch_fit.sh"
STEPS = 9  # 6 batches of 4 per rank and epoch: the runs cross an epoch boundary
TIMEOUT = 900  # a hung collective is a failure, not a stuck suite
# A stand-in for srun: SLURM_NNODES x SLURM_NTASKS_PER_NODE tasks on this machine, each with the
# per-task variables srun sets (Lightning's SLURMEnvironment reads PROCID, LOCALID and NODEID).
FAKE_SRUN = """#!/usr/bin/env bash
pids=()
for node in $(seq 0 $((SLURM_NNODES - 1))); do
  for local in $(seq 0 $((SLURM_NTASKS_PER_NODE - 1))); do
    SLURM_PROCID=$((node * SLURM_NTASKS_PER_NODE + local)) SLURM_NODEID=$node SLURM_LOCALID=$local "$@" &
    pids+=($!)
  done
done
rc=0
for pid in "${pids[@]}"; do wait "$pid" || rc=$?; done
exit $rc
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def environment(**extra: str) -> dict[str, str]:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore", PYTHON=sys.executable,
               PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    for key in [k for k in env if k.startswith(("SLURM_", "TORCHELASTIC_")) or k in ("MASTER_ADDR", "MASTER_PORT")]:
        del env[key]  # this machine's own scheduler, if any, is not the one simulated
    env.update(extra)
    return env


# ---------------------------------------------------------------------------------------------- data sources

@pytest.fixture(scope="module")
def synth_data(tmp_path_factory) -> Path:
    from stablemo.data.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("synth") / "synth", 60, 0, workers=1)


def folder_source(data: Path) -> list[str]:
    """`stablemo fit` flags that train from the folder reader (the memory-mapped split cache)."""
    return [f"--data.data_dir={data}"]


def shard_source(data: Path) -> list[str]:
    """`stablemo fit` flags that stream the same clips from `stablemo data shard` shards (8 clips a shard:
    each rank streams its own shards), made once beside the folder."""
    shards = data.parent / "shards"
    if not shards.exists():
        from stablemo.cli import main as cli

        assert cli(["data", "shard", str(data), "--out", str(shards), "--clips-per-shard", "8", "--workers", "1"]) == 0
    return ["--data.data_dir=null", f"--data.shards={shards}"]


SOURCES = {"folder": folder_source, "shards": shard_source}


@pytest.fixture(scope="module", params=sorted(SOURCES))
def source(request, synth_data) -> list[str]:
    return SOURCES[request.param](synth_data)


# ---------------------------------------------------------------------------------------------- runs

def run_config(folder: Path, data: Path, *callbacks: dict) -> Path:
    """The tiny test model, batch 4 per process, a checkpoint every step, each rank's weights saved
    at the end (cluster_probes.SaveRankWeights) and any further callbacks."""
    probes = [{"class_path": "cluster_probes.SaveRankWeights", "init_args": {"dirpath": str(folder / "ranks")}},
              *callbacks]
    # the config states 1 node of 1 device, as configs do: the launch scripts' layout flags must win
    return tiny_config(folder, data, **{"trainer.max_steps": STEPS, "trainer.accelerator": "cpu",
                                         "trainer.num_nodes": 1, "trainer.devices": 1,
                                         "trainer.callbacks": probes, "checkpoint.every_n_train_steps": 1})


def one_node_two_processes(folder: Path, data: Path, source: list[str], strategy: str = "ddp") -> Path:
    """The reference: Lightning's own launcher, 2 processes on one node."""
    cfg = run_config(folder, data)
    done = subprocess.run([sys.executable, "-m", "stablemo.cli", "fit", "--config", str(cfg), *source,
                           f"--trainer.strategy={strategy}", "--trainer.devices=2"],
                          cwd=REPO, env=environment(MASTER_PORT=str(free_port())), capture_output=True, text=True,
                          timeout=TIMEOUT, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return folder


def start_torchrun_nodes(cfg: Path, source: list[str], *extra: str) -> list[subprocess.Popen]:
    """scripts/cluster/torchrun_node.sh on 2 "nodes" (NODE_RANK 0 and 1), each its own process group."""
    port = str(free_port())
    nodes = []
    for rank in (0, 1):
        env = environment(NNODES="2", NODE_RANK=str(rank), MASTER_ADDR="127.0.0.1", MASTER_PORT=port,
                          GPUS_PER_NODE="1")
        with open(cfg.parent / f"node{rank}.log", "ab") as log:  # the node keeps its own descriptor
            nodes.append(subprocess.Popen(["bash", str(TORCHRUN), "--config", str(cfg), *source,
                                           "--trainer.accelerator=cpu", *extra], cwd=REPO, env=env, stdout=log,
                                          stderr=subprocess.STDOUT, start_new_session=True))
    return nodes


def wait_all(nodes: list[subprocess.Popen], folder: Path) -> None:
    for node in nodes:
        try:
            rc = node.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            kill_node(node)
            rc = "timeout"
        logs = "\n".join((folder / f"node{i}.log").read_text(errors="replace")[-2000:] for i in (0, 1))
        assert rc == 0, f"node exited with {rc}:\n{logs}"


def kill_node(node: subprocess.Popen) -> None:
    """SIGKILL a node's whole process group (torchrun and its worker), as a scheduler does."""
    try:
        os.killpg(node.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    node.wait()


def two_torchrun_nodes(folder: Path, data: Path, source: list[str]) -> Path:
    cfg = run_config(folder, data)
    wait_all(start_torchrun_nodes(cfg, source), folder)
    return folder


# ---------------------------------------------------------------------------------------------- comparisons

def max_difference(a: dict, b: dict) -> float:
    """The largest |a - b| over weights, EMA and Adam moments of two checkpoints (same step, keys)."""
    assert a["global_step"] == b["global_step"] == STEPS
    pairs = [(a["state_dict"], b["state_dict"]), (a["stablemo"]["ema"]["shadow"], b["stablemo"]["ema"]["shadow"])]
    opt_a, opt_b = a["optimizer_states"][0]["state"], b["optimizer_states"][0]["state"]
    assert opt_a.keys() == opt_b.keys()
    pairs += [({n: opt_a[i][n] for n in ("exp_avg", "exp_avg_sq")}, {n: opt_b[i][n] for n in ("exp_avg", "exp_avg_sq")})
              for i in opt_a]
    worst = 0.0
    for x, y in pairs:
        assert x.keys() == y.keys()
        for key in x:
            worst = max(worst, (x[key].double() - y[key].double()).abs().max().item())
    assert a["lr_schedulers"] == b["lr_schedulers"]
    return worst


def ranks_agree(folder: Path) -> None:
    """Every rank ends with the same weights and EMA, bit for bit, and they are the checkpoint's."""
    ranks = [torch.load(folder / "ranks" / f"rank{r}.pt", weights_only=True) for r in (0, 1)]
    assert ranks[0]["step"] == ranks[1]["step"] == STEPS
    for part in ("weights", "ema"):
        for key, value in ranks[0][part].items():
            assert torch.equal(value, ranks[1][part][key]), (part, key)
    saved = load_checkpoint_file(folder / "checkpoints" / "last.ckpt")
    for key, value in ranks[0]["weights"].items():
        assert torch.equal(saved["state_dict"]["model." + key], value), key


@pytest.fixture(scope="module")
def runs(source, synth_data, tmp_path_factory) -> dict[str, Path]:
    """The reference (1 node x 2 processes) and the torchrun run (2 nodes x 1 process), once per source."""
    root = tmp_path_factory.mktemp("runs")
    return {"one_node": one_node_two_processes(root / "one_node", synth_data, source),
            "torchrun": two_torchrun_nodes(root / "torchrun", synth_data, source)}


def test_two_torchrun_nodes_equal_one_node_of_two_processes(runs):
    one, two = (load_checkpoint_file(runs[k] / "checkpoints" / "last.ckpt") for k in ("one_node", "torchrun"))
    worst = max_difference(one, two)
    print(f"2 nodes (torchrun) vs 1 node x 2 processes after {STEPS} steps: max |diff| = {worst:.3g}")
    assert worst <= 1e-6
    ranks_agree(runs["torchrun"])
    ranks_agree(runs["one_node"])
    # the runs were really distributed: 2 nodes, one process each, the global rank from the node rank
    log = (runs["torchrun"] / "node1.log").read_text(errors="replace")
    assert "GLOBAL_RANK: 1, MEMBER: 2/2" in log


def test_sbatch_srun_line_under_simulated_slurm(runs, synth_data, source, tmp_path):
    """scripts/cluster/sbatch_fit.sh run as SLURM runs it on 2 nodes of 1 task (its `#SBATCH` lines are
    comments to bash): a stand-in srun starts both tasks; the result is the 1-node run's."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "srun").write_text(FAKE_SRUN)
    (bin_dir / "srun").chmod(0o755)
    cfg = run_config(tmp_path / "slurm", synth_data)
    env = environment(PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}", SLURM_JOB_NAME="stablemo",
                      SLURM_JOB_ID="4242", SLURM_NNODES="2", SLURM_NTASKS="2", SLURM_NTASKS_PER_NODE="1",
                      SLURM_NODELIST="127.0.0.1", MASTER_PORT=str(free_port()))
    done = subprocess.run(["bash", str(SBATCH), "--config", str(cfg), *source, "--trainer.accelerator=cpu"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=TIMEOUT, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "GLOBAL_RANK: 1, MEMBER: 2/2" in done.stdout + done.stderr  # SLURM's ranks, not a local launch
    slurm = load_checkpoint_file(tmp_path / "slurm" / "checkpoints" / "last.ckpt")
    worst = max_difference(load_checkpoint_file(runs["one_node"] / "checkpoints" / "last.ckpt"), slurm)
    print(f"2 nodes (sbatch's srun line, simulated SLURM) vs 1 node x 2 processes: max |diff| = {worst:.3g}")
    assert worst <= 1e-6
    ranks_agree(tmp_path / "slurm")


def test_a_kill_on_either_node_resumes_exactly(runs, synth_data, source, tmp_path):
    """Node 1's process is SIGKILLed mid-step 3, the job is torn down (node 0 is killed as a scheduler
    does), both nodes restart with `--ckpt_path last`; then node 0's process
    is killed mid-step 7 and both restart again. The end equals the uninterrupted torchrun run."""
    folder = tmp_path / "killed"
    for step, victim in ((3, 1), (7, 0)):
        cfg = run_config(folder, synth_data, {"class_path": "cluster_probes.KillAt",
                                              "init_args": {"step": step, "rank": victim}})
        resume = ["--ckpt_path=last"] if (folder / "checkpoints" / "last.ckpt").exists() else []
        nodes = start_torchrun_nodes(cfg, source, *resume)
        assert nodes[victim].wait(timeout=TIMEOUT) != 0  # its worker died: torchrun reports the failure
        kill_node(nodes[1 - victim])  # stuck in a collective or failed on the lost peer: torn down
        assert load_checkpoint_file(folder / "checkpoints" / "last.ckpt")["global_step"] == step
    cfg = run_config(folder, synth_data)
    wait_all(start_torchrun_nodes(cfg, source, "--ckpt_path=last"), folder)
    worst = max_difference(load_checkpoint_file(runs["torchrun"] / "checkpoints" / "last.ckpt"),
                           load_checkpoint_file(folder / "checkpoints" / "last.ckpt"))
    print(f"killed on node 1 at step 3 and on node 0 at step 7, resumed: max |diff| = {worst:.3g}")
    assert worst == 0.0
    ranks_agree(folder)


def test_fsdp_over_two_torchrun_nodes_streaming_shards(synth_data, tmp_path):
    """The scale path end to end: shards streamed, the model fully sharded over 2 nodes x 1 process
    (torchrun recipe, `--trainer.strategy=fsdp`), equal to the same FSDP run on 1 node x 2 processes."""
    source = shard_source(synth_data)
    one = one_node_two_processes(tmp_path / "one_node", synth_data, source, strategy="fsdp")
    two = tmp_path / "torchrun"
    wait_all(start_torchrun_nodes(run_config(two, synth_data), source, "--trainer.strategy=fsdp"), two)
    worst = max_difference(*(load_checkpoint_file(f / "checkpoints" / "last.ckpt") for f in (one, two)))
    print(f"FSDP, 2 nodes (torchrun) vs 1 node x 2 processes, from shards: max |diff| = {worst:.3g}")
    assert worst <= 1e-6
    ranks_agree(two)
