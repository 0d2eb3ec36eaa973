"""What every training run of the project shares: the one optimisation loop, the learning-rate schedule, the
distributed set-up, the NaN / inf guard, Ctrl-C handling, and the exit codes of the training CLIs.

:func:`optimise` is the loop of the generator (autoencoder, denoiser), the pose adapter, the force estimator and
ACT: each brings its loss (``batch_loss(step)``), what happens after an update (EMA, validation, snapshots) and
how it saves. A NaN / inf loss stops the run (:func:`check_loss` raises :class:`NonFiniteLoss`) before any
update from it, the last saved state kept; the first Ctrl-C inside :class:`StopOnInterrupt` lets the loop
finish and save its step, then it raises :class:`TrainingInterrupted`; :func:`agree` makes every rank of a
torch.distributed run (:func:`setup_distributed`) stop together. :func:`run_cli` maps these to one line on
stderr and the CLIs' exit codes (0 done, 1 NaN / inf loss, 2 bad options or data, 130 Ctrl-C).
"""

from __future__ import annotations

import math
import os
import signal
import sys
import warnings
from typing import Callable

import torch
import torch.distributed as dist
from torch.optim.lr_scheduler import CosineAnnealingLR, LinearLR, LRScheduler, SequentialLR
from tqdm.auto import tqdm
from controltac_il.cli import tty_only

from controltac_il.cli import guard


class NonFiniteLoss(RuntimeError):
    """The training loss became NaN or infinite; the run stopped, its last saved state is the last good one."""


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during training, after the current step was saved; ``str()`` says where and how to continue."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


def _stream_seed(seed: int, *key: int) -> int:
    """A 63-bit seed that is a pure function of (seed, key...)."""
    import numpy as np

    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint64)[0] >> 1)


class StepBatches(torch.utils.data.Sampler):
    """Index batches (a DataLoader ``batch_sampler``) for the updates ``start``, ``start + 1``, ...: epoch e's order
    is a permutation of the ``n`` items drawn from (seed, e), sharded ``rank::world`` under torch.distributed
    (padded to equal shards, as DistributedSampler does), and update u is batch u mod per_epoch of epoch
    u // per_epoch. So a run resumed at any step draws exactly the batches the uninterrupted run draws.

    drop_last: drop each epoch's incomplete last batch (as long as one full batch fits in a shard)."""

    def __init__(self, n: int, batch_size: int, seed: int, start: int = 0, rank: int = 0, world: int = 1,
                 drop_last: bool = True):
        if n < 1 or batch_size < 1 or start < 0:
            raise ValueError(f"StepBatches: need n >= 1, batch_size >= 1 and start >= 0, got {n}, {batch_size}, {start}")
        self.n, self.batch, self.seed, self.start, self.rank, self.world = n, batch_size, seed, start, rank, world
        shard = -(-n // world)
        self.shard = shard
        full = shard // batch_size
        self.per_epoch = full if drop_last and full else -(-shard // batch_size)

    def epoch_order(self, epoch: int) -> list[int]:
        """This rank's item order in ``epoch``."""
        g = torch.Generator().manual_seed(_stream_seed(self.seed, epoch))
        order = torch.randperm(self.n, generator=g).tolist()
        order += order[: self.shard * self.world - self.n]
        return order[self.rank::self.world]

    def __iter__(self):
        epoch, b = divmod(self.start, self.per_epoch)
        while True:
            order = self.epoch_order(epoch)
            for i in range(b, self.per_epoch):
                yield order[i * self.batch:(i + 1) * self.batch]
            epoch, b = epoch + 1, 0


def seed_update(seed: int, step: int, rank: int = 0) -> None:
    """Seed torch's global RNG (dropout, sampled noise) for update ``step`` from (seed, step, rank), so that a run
    resumed at any step makes the same draws as the uninterrupted run, with no RNG state to save."""
    torch.manual_seed(_stream_seed(seed, step, rank))


def lr_schedule(optimizer: torch.optim.Optimizer, peaks: list[float], total: int, warmup: int,
                min_lr: float | None = None, resume: dict | None = None, step: int = 0) -> LRScheduler:
    """Linear warm-up over ``warmup`` steps (update i gets peak * (i + 1) / warmup), then a cosine decay to
    ``min_lr`` at update ``total`` (torch's LinearLR -> CosineAnnealingLR), or constant when ``min_lr`` is None.

    ``peaks``: each param group's peak LR (this run's settings). ``resume``: the ``lr_schedule`` entry of a
    saved run state; restored as it was when the settings match, else (e.g. more steps) this run's schedule
    continues from update ``step``. Call it after the optimizer state is loaded.
    """
    for g, peak in zip(optimizer.param_groups, peaks, strict=True):
        g["lr"] = g["initial_lr"] = peak
    warm = LinearLR(optimizer, 1 / warmup if warmup else 1.0, 1.0, total_iters=max(warmup - 1, 0))
    if min_lr is None:
        sched = warm
    else:
        cos = CosineAnnealingLR(optimizer, T_max=max(1, total - warmup), eta_min=min_lr)
        sched = SequentialLR(optimizer, [warm, cos], milestones=[warmup]) if warmup else cos
    sched.settings = {"peaks": list(peaks), "total": total, "warmup": warmup, "min_lr": min_lr}
    if resume is not None and resume.get("settings") == sched.settings:
        sched.load_state_dict(resume["state"])
        for g, lr in zip(optimizer.param_groups, sched.get_last_lr()):
            g["lr"] = lr
    else:
        with warnings.catch_warnings():  # stepping the schedule without optimizer steps, on purpose
            warnings.simplefilter("ignore", UserWarning)
            for _ in range(step):
                sched.step()
    return sched


class StopOnInterrupt:
    """Within the block the first Ctrl-C (SIGINT) only sets ``requested``: the training loop finishes its step,
    saves and stops (:class:`TrainingInterrupted`); a second Ctrl-C interrupts at once. Left as is where
    Python's own handler is not installed (SIGINT ignored, or not the main thread)."""

    requested = False

    def __enter__(self) -> "StopOnInterrupt":
        self.requested, self._old = False, None
        try:
            if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
                self._old = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not the main thread
            self._old = None
        return self

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


def agree(*flags: bool) -> list[bool]:
    """Each flag OR-ed over the processes of a torch.distributed run (as is without one), so every rank stops
    together."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return [bool(f) for f in flags]
    t = torch.tensor([float(f) for f in flags])
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return [bool(v) for v in t.tolist()]


def check_loss(loss: float, step: int, kept: str, grad_norm: float = 0.0) -> None:
    """Raise :class:`NonFiniteLoss` when ``loss`` (of update ``step``) or its gradients' norm is NaN or infinite;
    ``kept`` says which saved state is the last good one."""
    if not math.isfinite(loss):
        what = f"the loss is {loss}"
    elif not math.isfinite(grad_norm):
        what = f"the loss is {loss:.4g} but its gradients' norm is {grad_norm}"
    else:
        return
    raise NonFiniteLoss(f"training stopped at step {step}: {what}; no update was applied, {kept} "
                        "(lower the learning rate or check the data for NaN / outliers, then --resume)")


def setup_distributed() -> tuple[int, int]:
    """(rank, world size); initialises the process group when launched by torchrun with WORLD_SIZE > 1 (nccl on
    CUDA, gloo on CPU)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    return (dist.get_rank(), dist.get_world_size()) if world > 1 and dist.is_initialized() else (0, 1)


def barrier(world: int) -> None:
    if world > 1:
        dist.barrier()


def wrap(model: torch.nn.Module, world: int) -> torch.nn.Module:
    """``model`` under DistributedDataParallel when ``world`` > 1 (gradients averaged across ranks)."""
    return torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model


def parse_device(device) -> torch.device:
    """``device`` (a name such as cpu, cuda, cuda:0, or a torch.device) as a torch.device; ValueError naming
    ``device`` for anything torch cannot read as one, or a CUDA device this machine does not have."""
    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise ValueError(f"device: expected a torch device such as cpu, cuda or cuda:0, got {device!r}") from None
    if parsed.type == "cuda" and (parsed.index or 0) >= torch.cuda.device_count():  # 0 without CUDA
        raise ValueError(f"device: {str(parsed)!r}, but this machine has {torch.cuda.device_count()} CUDA device(s); "
                         "use cpu")
    return parsed


def device_problem(name: str) -> str | None:
    """Why ``name`` cannot be trained on here (``parse_device``'s line, naming ``--device``), or None."""
    try:
        device = parse_device(name)
    except ValueError as exc:
        return f"--{exc}"
    return None if device.type in ("cpu", "cuda") else f"--device: expected cpu, cuda or cuda:N, got {name!r}"


def device_name(device: str | torch.device) -> str:
    """What a model card records of where it trained: the GPU's name, or "cpu"."""
    device = torch.device(device)
    return torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"


def optimise(step: int, total: int, batch_loss: Callable[[int], torch.Tensor | dict], optimizer: torch.optim.Optimizer,
             scheduler, params, save: Callable[[int, float], None] | None, every: int, desc: str, *, rank: int = 0,
             grad_clip: float = 1.0, after_step: Callable[[int, object], None] | None = None,
             state: str | None = None, progress: bool = True) -> int:
    """Optimiser updates ``step`` .. ``total``; returns the step reached (``total``).

    batch_loss(step): the loss of one batch (a scalar tensor, or a dict with ``"loss"`` and other outputs).
    Each update: backward, NaN / inf check (every rank agrees), gradients clipped to ``grad_clip`` (0 = none),
    optimizer and ``scheduler`` step, then ``after_step(step, outputs)`` (EMA, logging, validation).
    save(step, smoothed loss): on rank 0 every ``every`` steps (0 = only at the end), at the end, and at a Ctrl-C;
    None = nothing saved. state: the saved state's name for messages (None = nothing has been saved)."""
    bar = tqdm(total=total, initial=step, desc=desc, unit="step", disable=True if rank != 0 else tty_only(progress), dynamic_ncols=True)
    loss_ema, saved = None, step if state is not None and step > 0 else None
    with StopOnInterrupt() as stop:
        try:
            while step < total:
                out = batch_loss(step)
                loss = out["loss"] if isinstance(out, dict) else out
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                value = loss.item()
                # the gradients clipped to norm grad_clip (0: measured only): a finite loss can have NaN gradients
                norm = float(torch.nn.utils.clip_grad_norm_(params, grad_clip or math.inf))
                ok = math.isfinite(value) and math.isfinite(norm)
                bad, stop_now = agree(not ok, stop.requested)
                if bad:  # this rank's values, or a NaN loss where another rank's were not finite
                    check_loss(value if not ok else math.nan, step + 1,
                               f"{state} holds step {saved}, the last good state" if saved is not None
                               else "no state had been saved yet", norm)
                optimizer.step()
                scheduler.step()
                step += 1
                if after_step is not None:
                    after_step(step, out)
                loss_ema = value if loss_ema is None else 0.98 * loss_ema + 0.02 * value
                bar.update()
                bar.set_postfix(loss=f"{loss_ema:.4f}")
                if save is not None and rank == 0 and ((every and step % every == 0) or step == total or stop_now):
                    save(step, loss_ema)
                    saved = step
                if stop_now and step < total:
                    where = f"{state} holds step {step} of {total}; continue with --resume" if save is not None \
                        else "nothing was saved"
                    raise TrainingInterrupted(f"interrupted (Ctrl-C) at step {step}: {where}")
        finally:
            bar.close()
    return step


def run_cli(prog: str, job: Callable[[], object]) -> int:
    """Run a training CLI's ``job`` and return its exit code, each failure one line on stderr: 0 done;
    1 stopped on a NaN / inf loss; 2 bad options, data, output folder or checkpoint (ValueError / OSError, of
    which CheckpointError and OutputInUse are kinds); 130 Ctrl-C (inside a step: after saving it)."""
    try:
        return guard(prog, lambda: job() and 0, "interrupted (Ctrl-C) outside a training step; files already "
                                                "written are complete (atomic writes)")
    except NonFiniteLoss as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
