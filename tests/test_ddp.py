"""DDP on CPU (gloo, 2 processes): each rank's slice of the global batch gives the single-process gradient."""

import os
import socket

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import nn

import mop.train as mt
from mop.config import to_dict
from mop.models import build_model
from mop.runs import load_model
from mop.train.device import distributed_session, init_distributed
from tests.test_train import tiny_config


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world: int, port: int, out_dir: str) -> None:
    os.environ.update(
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
        WORLD_SIZE=str(world),
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        OMP_NUM_THREADS="1",
    )
    torch.set_num_threads(1)
    with distributed_session():
        _ranks_train(rank, world, out_dir)
    assert not dist.is_initialized()  # closed by every rank before it exits (as `mop train` does)


def _ranks_train(rank: int, world: int, out_dir: str) -> None:
    assert init_distributed() == (rank, world)
    config = mt.resolve_config(tiny_config())
    torch.manual_seed(0)
    model = build_model(config.model)
    ddp = nn.parallel.DistributedDataParallel(mt.LossModule(model))
    inputs, targets = mt.TrainingData(config, torch.device("cpu")).batch()  # global batch, same on all ranks
    b = config.train.batch_size // world
    ddp(inputs[rank * b : (rank + 1) * b], targets[rank * b : (rank + 1) * b]).backward()
    torch.save({n: p.grad for n, p in model.named_parameters()}, f"{out_dir}/grad{rank}.pt")
    mt.train(tiny_config(steps=2), f"{out_dir}/run", progress=False)  # the trainer itself under DDP


def test_ddp_gradients_equal_single_process(tmp_path):
    mp.spawn(_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    config = mt.resolve_config(tiny_config())
    torch.manual_seed(0)
    model = build_model(config.model)
    model.loss(*mt.TrainingData(config, torch.device("cpu")).batch()).backward()
    for rank in range(2):
        grads = torch.load(tmp_path / f"grad{rank}.pt", weights_only=True)
        for name, p in model.named_parameters():
            torch.testing.assert_close(grads[name], p.grad, rtol=1e-5, atol=1e-7)
    single = mt.train(tiny_config(steps=2), tmp_path / "single", progress=False)
    distributed, _ = load_model(tmp_path / "run")
    reference, _ = load_model(single)
    for a, b in zip(distributed.parameters(), reference.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5)  # Adam: two steps of size ~lr = 3e-4
    assert (tmp_path / "run" / "done.json").exists()


def test_torchrun_two_ranks_train_like_one_process(tmp_path):
    """`torchrun --nproc_per_node 2 -m mop train` ends with the weights of a one-process run.

    Both see the same global batch each step.
    """
    import json
    import subprocess
    import sys

    from mop.checkpoint import load_tensors

    config = tiny_config(steps=4)
    given = tmp_path / "config.json"  # every key: `mop train` alone would start from the CPU preset
    given.write_text(json.dumps(to_dict(config, omit_defaults=False)))
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    command += ["-m", "mop", "train", str(given), "--out", str(tmp_path / "ddp")]
    command += ["model.features=given"]  # as the config's default (left out of to_dict): no preset's auto
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[:3000]  # the ranks' own errors come before torchrun's
    mt.train(config, tmp_path / "single", progress=False)
    ddp, single = (load_tensors(tmp_path / d / "model.safetensors")[0] for d in ("ddp", "single"))
    assert ddp.keys() == single.keys()
    for name in single:
        torch.testing.assert_close(ddp[name], single[name], rtol=1e-4, atol=1e-5)
