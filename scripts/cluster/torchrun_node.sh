#!/usr/bin/env bash
# One node of a multi-node `stablemo fit` through torchrun: run this same line on every node, each
# with its own NODE_RANK (0 .. NNODES-1); MASTER_ADDR is node 0's address, reachable from all nodes.
#
#   NNODES=4 NODE_RANK=0 MASTER_ADDR=10.0.0.1 GPUS_PER_NODE=8 \
#     bash scripts/cluster/torchrun_node.sh --config configs/synth_small.yaml --trainer.accelerator=gpu
#
# Every argument after the script goes to `stablemo fit`, before the node layout flags, which so win
# over a config's own trainer.num_nodes/devices; add `--ckpt_path last` to resume (a first run with it
# starts from scratch). tests/test_multinode.py runs exactly this file, 2 nodes x 1 process
# on 127.0.0.1 with gloo.
set -euo pipefail
: "${NNODES:?set NNODES (number of nodes)}"
: "${NODE_RANK:?set NODE_RANK (this node, 0 .. NNODES-1)}"
: "${MASTER_ADDR:?set MASTER_ADDR (node 0 address)}"
MASTER_PORT=${MASTER_PORT:-29500}
GPUS_PER_NODE=${GPUS_PER_NODE:-1}   # processes per node, one per GPU
PYTHON=${PYTHON:-python}            # the environment's interpreter (e.g. .venv/bin/python)
# torch.distributed.run is torchrun; static rendezvous: the node ranks are given, node 0 hosts the store
exec "$PYTHON" -m torch.distributed.run \
  --nnodes "$NNODES" --nproc-per-node "$GPUS_PER_NODE" --node-rank "$NODE_RANK" \
  --master-addr "$MASTER_ADDR" --master-port "$MASTER_PORT" \
  -m stablemo.cli fit "$@" --trainer.num_nodes "$NNODES" --trainer.devices "$GPUS_PER_NODE"
