"""nerfstudio's data-parallel training (`--machine.num-devices N`) with SS-NeRF's pipeline, model and datamanager, as
far as it can run without GPUs: two CPU processes on the gloo backend, each running nerfstudio's own Trainer with
world size 2 (its `VanillaPipeline` wraps the model in DistributedDataParallel).

Two things of nerfstudio's path need CUDA and are replaced here, and only these: its launcher asserts CUDA before
starting the processes (so the process group is made here, as `_distributed_worker` makes it, with gloo), and its
pipeline passes `device_ids=[local_rank]` to DDP and to `dist.barrier`, which only GPU modules and NCCL accept.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from nerfstudio.pipelines import base_pipeline

from test_training import lite_config, write_learnable_dataset

STEPS = 6


class CpuDDP(torch.nn.parallel.DistributedDataParallel):
    """DDP as nerfstudio builds it, without the GPU-only device_ids (a CPU module takes None)."""

    def __init__(self, module, device_ids=None, **kwargs) -> None:
        super().__init__(module, **kwargs)


BARRIER = dist.barrier


def cpu_barrier(*args, device_ids=None, **kwargs):
    """`dist.barrier` without the NCCL-only device_ids."""
    return BARRIER(*args, **kwargs)


def worker(rank: int, data: str, output: str, store: str) -> None:
    """One rank: nerfstudio's `train_loop` (seed + rank, Trainer with world size 2), recording its losses and final
    parameters."""
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{store}", world_size=2, rank=rank)
    base_pipeline.DDP = CpuDDP  # type: ignore[attr-defined]
    base_pipeline.dist.barrier = cpu_barrier  # type: ignore[assignment]
    from nerfstudio.scripts.train import _set_random_seed

    config = lite_config(Path(data), Path(output), iterations=STEPS)
    config.machine.num_devices = 2
    config.steps_per_save = STEPS
    _set_random_seed(config.machine.seed + rank)
    trainer = config.setup(local_rank=rank, world_size=2)
    trainer.setup()
    assert isinstance(trainer.pipeline._model, torch.nn.parallel.DistributedDataParallel)
    losses = []
    original = trainer.train_iteration

    def recording(step: int):
        loss, loss_dict, metrics = original(step)
        losses.append({key: float(value) for key, value in loss_dict.items()})
        return loss, loss_dict, metrics

    trainer.train_iteration = recording  # type: ignore[method-assign]
    trainer.train()
    model = trainer.pipeline.model
    parameters = torch.cat([parameter.detach().flatten().double() for parameter in model.parameters()])
    torch.save(parameters, Path(output) / f"parameters_{rank}.pt")
    (Path(output) / f"losses_{rank}.json").write_text(json.dumps(losses))
    dist.barrier()
    dist.destroy_process_group()


def test_two_process_data_parallel_training_keeps_the_ranks_in_step(tmp_path: Path) -> None:
    data = write_learnable_dataset(tmp_path / "data")
    output = tmp_path / "outputs"
    output.mkdir()
    mp.spawn(worker, args=(str(data), str(output), str(tmp_path / "store")), nprocs=2, join=True)

    first, second = (torch.load(output / f"parameters_{rank}.pt") for rank in (0, 1))
    assert torch.equal(first, second)  # gradients were all-reduced: both ranks hold one model
    losses = [json.loads((output / f"losses_{rank}.json").read_text()) for rank in (0, 1)]
    assert len(losses[0]) == len(losses[1]) == STEPS
    assert set(losses[0][0]) >= {"rgb_loss", "semantics_loss", "normals_loss", "shading_loss", "keypoints_loss",
                                 "edges_loss"}
    assert losses[0][0]["rgb_loss"] != losses[1][0]["rgb_loss"]  # each rank trained on rays of its own
    checkpoints = list(output.rglob("step-*.ckpt"))
    assert [path.name for path in checkpoints] == [f"step-{STEPS - 1:09d}.ckpt"]  # rank 0 alone saves
    # what `ns-eval` does with it on one device: nerfstudio strips DDP's "module." and the model is rank 0's
    single = lite_config(data, output, iterations=STEPS).pipeline.setup(device="cpu", test_mode="test")
    single.load_pipeline(torch.load(checkpoints[0], map_location="cpu")["pipeline"], STEPS - 1)
    loaded = torch.cat([parameter.detach().flatten().double() for parameter in single.model.parameters()])
    assert torch.equal(loaded, first)
