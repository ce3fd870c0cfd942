"""The per-mesh optimisation loop that every learned method shares.

A *model* produces the candidate: linear-light textures (one per material, None where the
material is untextured) and optionally new UVs. The loop renders K random training views of
the candidate through the protocol renderer, compares them with renders of the original
(L2 plus a weighted 1 - SSIM on the sRGB images, foreground only), and steps AdamW with a
warm-up and cosine decay. Every ``validate_every`` steps it scores the candidate on the
validation set Q and keeps the best state. It stops at a step count, a wall-clock budget or a
plateau, and reports progress events that the CLI's progress bar and the desktop app consume.

Training views are cached once (a :class:`~geoscaler.views.ViewCache`: G-buffers, references
and, for models that keep the mesh's UVs, texture taps), so a step costs only texel gathers and
their gradients. :func:`optimize` is three parts: :func:`cache_training_views`,
:func:`train_step` and :func:`validate`.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import torch

from geoscaler.cameras import Camera, sample_training_cameras
from geoscaler.metrics import SSIMLoss, psnr_fg
from geoscaler.render import Renderer
from geoscaler.texture import build_mip_chain, quantize_linear
from geoscaler.views import ViewCache, ViewSet

TRAINING_RANGE = (1.5, 4.2)
"""The loop's default training distances: wider than the protocol's range S on both sides, so
the texture holds up from the near robustness set (1.5, magnified texels) to the far one (4.0,
where coarser mip levels of the candidate are shown). See the README's "training range" note."""
# Under a time budget, the training pool stops growing once this share of it is spent.
CACHING_SHARE = 0.4


class Model(Protocol):
    """What the loop optimises."""

    def parameters(self) -> Sequence[torch.Tensor]: ...

    def candidate(self) -> tuple[list[torch.Tensor | None], torch.Tensor | None]:
        """``(textures, uvs)``: per material ``(h, w, 3)`` linear texture or None, and
        ``(V, 2)`` UVs or None to keep the mesh's own."""
        ...

    def project(self) -> None:
        """Called after each step to keep parameters valid (e.g. texels in [0, 1])."""
        ...


@dataclass
class OptimizeConfig:
    """Settings of the loop.

    Attributes:
        steps: maximum optimisation steps.
        time_budget: wall-clock seconds for everything, cache building included (None: none).
        views_per_step: K training views rendered per step.
        pool_views: training cameras cached up front, drawn from ``distances``.
        distances: camera distance range of the training views.
        lr: peak learning rate; warm-up over ``warmup_steps``, then cosine decay to 0.
        weight_decay: AdamW weight decay.
        ssim_weight: weight of ``1 - SSIM`` beside the L2 term.
        validate_every: steps between validations on Q (the last step always validates).
        patience: validations without improvement before stopping (None: never).
        seed: seeds the cameras and the view order.
    """

    steps: int = 400
    time_budget: float | None = None
    views_per_step: int = 4
    pool_views: int = 48
    distances: tuple[float, float] = TRAINING_RANGE
    lr: float = 0.02
    weight_decay: float = 0.0
    warmup_steps: int = 10
    ssim_weight: float = 0.1
    validate_every: int = 50
    patience: int | None = None
    seed: int = 0


@dataclass
class ProgressEvent:
    """A report from the loop.

    Attributes:
        phase: ``"caching"``, ``"step"``, ``"validation"`` or ``"done"``.
        step: steps completed.
        total_steps: the step limit.
        elapsed: seconds since the loop started.
        loss: the latest training loss (nan before the first step).
        validation_psnr: PSNR-fg on Q of this validation (``"validation"`` events).
        best_psnr: best validation PSNR-fg so far.
        done / total: progress within the caching phase.
        candidate: returns the current ``(textures, uvs)``, detached, on request: linear
            textures and UVs (None when the model keeps the mesh's own).
    """

    phase: str
    step: int
    total_steps: int
    elapsed: float
    loss: float = math.nan
    validation_psnr: float | None = None
    best_psnr: float = -math.inf
    done: int = 0
    total: int = 0
    candidate: Callable[[], tuple[list[torch.Tensor | None], torch.Tensor | None]] | None = field(
        default=None, repr=False
    )


class Controller:
    """Pause, resume and stop a running loop from another thread."""

    def __init__(self):
        self._running = threading.Event()
        self._running.set()
        self._stop = threading.Event()

    def pause(self) -> None:
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    def stop(self) -> None:
        self._stop.set()
        self._running.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    def wait_while_paused(self) -> None:
        self._running.wait()


@dataclass
class PerceptualTerm:
    """``weight * loss(image, reference)`` on the object's crop of two ``(H, W, 3)`` images."""

    loss: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    weight: float


def rendering_loss(
    image: torch.Tensor,
    reference: torch.Tensor,
    foreground: torch.Tensor,
    ssim_weight: float,
    perceptual: PerceptualTerm | None = None,
) -> torch.Tensor:
    """The training loss of one view, on sRGB images:

    ``mean_fg (image - reference)^2 + ssim_weight (1 - SSIM_fg) + perceptual`` (the last two
    on the crop around the object).
    """
    mse = (image - reference).square().mean(-1)[foreground].mean()
    if ssim_weight == 0 and perceptual is None:
        return mse
    rows = torch.nonzero(foreground.any(1)).squeeze(1)
    cols = torch.nonzero(foreground.any(0)).squeeze(1)
    pad = 8  # keep the SSIM window's context around the object
    r0, r1 = max(int(rows[0]) - pad, 0), min(int(rows[-1]) + pad + 1, image.shape[0])
    c0, c1 = max(int(cols[0]) - pad, 0), min(int(cols[-1]) + pad + 1, image.shape[1])
    if r1 - r0 < 11 or c1 - c0 < 11:
        return mse
    crop = (slice(r0, r1), slice(c0, c1))
    loss = mse
    if ssim_weight != 0:
        ssim = SSIMLoss()(image[crop][None], reference[crop][None], foreground[crop][None])
        loss = loss + ssim_weight * ssim
    if perceptual is not None:
        loss = loss + perceptual.weight * perceptual.loss(image[crop], reference[crop])
    return loss


@dataclass
class OptimizeResult:
    """The best validated candidate, finished as it ships (:func:`finish`), and how the run
    went; ``best_psnr`` is that finished candidate's validation score."""

    textures: list[torch.Tensor | None]
    uvs: torch.Tensor | None
    steps: int
    best_step: int
    best_psnr: float
    stopped_by: str
    seconds: float
    history: list[dict] = field(default_factory=list)


def view_loss(
    cache: ViewCache,
    view: int,
    textures: Sequence[torch.Tensor | None],
    uvs: torch.Tensor | None,
    ssim_weight: float,
    perceptual: PerceptualTerm | None = None,
) -> torch.Tensor:
    """:func:`rendering_loss` of a candidate in the cached view ``view``."""
    image = cache.render(view, textures, uvs)
    views = cache.views
    return rendering_loss(
        image, views.references[view], views.foreground[view], ssim_weight, perceptual
    )


def cache_training_views(
    renderer: Renderer,
    sizes: Sequence[tuple[int, int] | None],
    config: OptimizeConfig,
    keeps_uvs: bool,
    cameras: Sequence[Camera] | None = None,
    start: float | None = None,
    emit: Callable[[ProgressEvent], None] | None = None,
) -> tuple[ViewCache, list[torch.Tensor | None]]:
    """The training pool, and per material the ``(h, w)`` bool texels its views read.

    Args:
        renderer: the mesh's renderer.
        sizes: per material the candidate's texture ``(h, w)`` (None: untextured).
        config: the pool's size and distances, the seed, the time budget.
        keeps_uvs: cache texture taps (and find the texels read) for the mesh's own UVs.
        cameras: the views to cache (default: ``config.pool_views`` drawn from
            ``config.distances``).
        start: the ``time.perf_counter()`` the time budget counts from; under a budget the
            pool stops growing once :data:`CACHING_SHARE` of it is spent (at least
            ``config.views_per_step`` views are cached).
        emit: receives ``"caching"`` events.
    """
    start = time.perf_counter() if start is None else start
    cameras = cameras or sample_training_cameras(config.pool_views, config.seed, config.distances)

    def report(done: int, total: int) -> None:
        if emit:
            elapsed = time.perf_counter() - start
            emit(ProgressEvent("caching", 0, config.steps, elapsed, done=done, total=total))

    deadline = None
    if config.time_budget is not None:  # leave most of the budget to the optimisation itself
        deadline = start + CACHING_SHARE * config.time_budget
    pool = ViewSet(renderer, cameras, report, deadline, config.views_per_step)
    train = ViewCache(pool, sizes, keeps_uvs)
    # Texels no training view reads, filled from the charts in every validated candidate
    # (found once: this depends only on the taps).
    seen = [seen_texels(train, i) if keeps_uvs and s else None for i, s in enumerate(sizes)]
    return train, seen


def train_step(
    train: ViewCache,
    model: Model,
    optimizer: torch.optim.Optimizer,
    views: Sequence[int],
    config: OptimizeConfig,
    lr_factor: Callable[[], float],
    perceptual: PerceptualTerm | None = None,
) -> float:
    """One step on the mean loss of the training ``views``; returns the loss.

    ``lr_factor()`` is read after the backward pass (so that a budgeted schedule sees the time
    the step took) and scales ``config.lr`` for this step.
    """
    optimizer.zero_grad(set_to_none=True)
    textures, uvs = model.candidate()
    losses = [view_loss(train, i, textures, uvs, config.ssim_weight, perceptual) for i in views]
    loss = torch.stack(losses).mean()
    loss.backward()
    factor = lr_factor()
    for group in optimizer.param_groups:
        group["lr"] = config.lr * factor
    optimizer.step()
    model.project()
    return loss.item()


Candidate = tuple[list[torch.Tensor | None], torch.Tensor | None]
"""``(textures, uvs)``: per material a ``(h, w, 3)`` linear texture or None, and ``(V, 2)``
UVs or None (the mesh's own)."""


def finish(
    textures: Sequence[torch.Tensor | None], seen: Sequence[torch.Tensor | None]
) -> list[torch.Tensor | None]:
    """The candidate's textures as they will ship, before 8-bit encoding: detached, and
    texels that no training view reads filled from their charts (:func:`fill_unseen`; ``seen``
    per material, None: nothing to fill)."""
    finished = []
    for texture, mask in zip(textures, seen, strict=True):
        if texture is not None:
            texture = texture.detach()
            texture = texture.clone() if mask is None else fill_unseen(texture, mask)
        finished.append(texture)
    return finished


@torch.no_grad()
def validate(
    cache: ViewCache, model: Model, seen: Sequence[torch.Tensor | None] | None = None
) -> tuple[float, Candidate]:
    """Mean PSNR-fg over the cached validation views of the candidate as it will ship
    (:func:`finish`, then 8-bit quantised), and that finished candidate: what is validated is
    what ships."""
    textures, uvs = model.candidate()
    textures = finish(textures, seen or [None] * len(textures))
    uvs = None if uvs is None else uvs.detach().clone()
    shipped = [None if t is None else quantize_linear(t) for t in textures]
    views = cache.views
    values = [
        psnr_fg(
            cache.render(i, shipped, uvs)[None],
            views.references[i : i + 1],
            views.foreground[i : i + 1],
        )
        for i in range(len(views))
    ]
    return float(torch.cat(values).mean()), (textures, uvs)


def optimize(
    renderer: Renderer,
    model: Model,
    config: OptimizeConfig,
    validation: ViewCache,
    on_event: Callable[[ProgressEvent], None] | None = None,
    controller: Controller | None = None,
    keeps_uvs: bool = True,
    perceptual: PerceptualTerm | None = None,
    training_cameras: Sequence[Camera] | None = None,
    started_at: float | None = None,
) -> OptimizeResult:
    """Optimise ``model`` so that renders of its candidate match renders of the original.

    Args:
        renderer: the mesh's renderer (its device is the device of the run).
        model: the candidate's parameters.
        config: loop settings.
        validation: the cached validation views (Q), with taps for the candidate's texture
            sizes (which the training pool's taps take too).
        on_event: receives :class:`ProgressEvent` reports.
        controller: lets another thread pause, resume or stop the loop.
        keeps_uvs: the model never changes UVs, so texture taps can be cached.
        perceptual: an extra loss term (the network's VGG-19 term).
        training_cameras: the views to train on (default: ``config.pool_views`` cameras drawn
            from ``config.distances``). Methods never train on the validation cameras; the
            texel-ceiling benchmark does, to bound what any texture could reach there.
        started_at: the ``time.perf_counter()`` the time budget counts from (default: now), so
            that a method's own set-up counts too.

    Returns:
        The best validated candidate (detached) and the run's history.
    """
    start = time.perf_counter() if started_at is None else started_at
    controller = controller or Controller()
    emit = on_event or (lambda event: None)
    train, seen = cache_training_views(
        renderer, validation.sizes, config, keeps_uvs, training_cameras, start, emit
    )
    optimizer = torch.optim.AdamW(
        list(model.parameters()), lr=config.lr, weight_decay=config.weight_decay
    )
    generator = torch.Generator().manual_seed(config.seed)

    def candidate() -> Candidate:
        with torch.no_grad():
            textures, uvs = model.candidate()
            copies = [None if t is None else t.detach().clone() for t in textures]
            return copies, None if uvs is None else uvs.detach().clone()

    best = _Best()
    validation_start = time.perf_counter()
    best.offer(*validate(validation, model, seen), 0)  # the start is a candidate too
    # A run under a budget stops early enough for one more step and the final validation (with
    # half a validation's time to spare: on a busy machine one takes longer than the next).
    reserve = 1.5 * (time.perf_counter() - validation_start)
    validated_step = 0
    history: list[dict] = []
    step, loss_value, stopped_by = 0, math.nan, "steps"
    step_seconds = 0.0
    loop_start = time.perf_counter()
    while step < config.steps:
        controller.wait_while_paused()
        if controller.stopped:
            stopped_by = "stopped"
            break
        step_start = time.perf_counter()
        if (
            config.time_budget is not None
            and step_start + step_seconds + reserve - start > config.time_budget
        ):
            stopped_by = "time budget"
            break
        views = torch.randperm(len(train), generator=generator)[: config.views_per_step]
        loss_value = train_step(
            train,
            model,
            optimizer,
            views.tolist(),
            config,
            lambda at=step: _learning_rate_factor(
                at, _time_spent(time.perf_counter(), start, loop_start, config), config
            ),
            perceptual,
        )
        step += 1
        step_seconds = time.perf_counter() - step_start
        elapsed = time.perf_counter() - start
        emit(
            ProgressEvent(
                "step",
                step,
                config.steps,
                elapsed,
                loss_value,
                best_psnr=best.psnr,
                candidate=candidate,
            )
        )
        history.append({"step": step, "loss": loss_value, "elapsed": elapsed})
        if step % config.validate_every == 0 or step == config.steps:
            psnr, finished = validate(validation, model, seen)
            validated_step = step
            improved = best.offer(psnr, finished, step)
            history[-1]["validation_psnr_fg"] = psnr
            emit(
                ProgressEvent(
                    "validation",
                    step,
                    config.steps,
                    time.perf_counter() - start,
                    loss_value,
                    psnr,
                    best.psnr,
                    candidate=candidate,
                )
            )
            if not improved and config.patience is not None and best.stale >= config.patience:
                stopped_by = "plateau"
                break

    if validated_step != step:  # stopped between validations: the current state may be better
        best.offer(*validate(validation, model, seen), step)
    seconds = time.perf_counter() - start
    emit(ProgressEvent("done", step, config.steps, seconds, loss_value, None, best.psnr))
    return OptimizeResult(
        best.textures, best.uvs, step, best.step, best.psnr, stopped_by, seconds, history
    )


def _time_spent(now: float, start: float, loop_start: float, config: OptimizeConfig) -> float:
    """Fraction of the optimisation's share of the budget used at ``now``: the share runs
    from the first step (``loop_start``) to the budget's end (0 without a budget)."""
    if config.time_budget is None:
        return 0.0
    span = start + config.time_budget - loop_start
    return 1.0 if span <= 0 else (now - loop_start) / span


def _learning_rate_factor(step: int, time_spent: float, config: OptimizeConfig) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine decay to 0.

    The decay follows whichever runs out first, the steps or the time budget (so a budgeted
    run ends at a low learning rate too); with a budget the schedule, and so the result, depends
    on the machine's speed.
    """
    if step < config.warmup_steps:
        return (step + 1) / config.warmup_steps
    span = max(config.steps - config.warmup_steps, 1)
    progress = max((step - config.warmup_steps) / span, time_spent)
    return 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


class _Best:
    """The best validated candidate so far."""

    def __init__(self):
        self.psnr = -math.inf
        self.step = -1
        self.stale = 0
        self.textures: list[torch.Tensor | None] = []
        self.uvs: torch.Tensor | None = None

    def offer(self, psnr: float, candidate: Candidate, step: int) -> bool:
        """Keep ``candidate`` (finished, as validated) if it scored better than the best."""
        if psnr <= self.psnr:
            self.stale += 1
            return False
        self.textures, self.uvs = candidate
        self.psnr, self.step, self.stale = psnr, step, 0
        return True


def seen_texels(cache: ViewCache, material: int) -> torch.Tensor:
    """``(h, w)`` bool: level-0 texels that some cached view's taps read, through any level.

    A texel is seen when a tap of a view reads it at level 0, or reads a coarser-level texel
    whose box average includes it.
    """
    layout = cache.layouts[material]
    usage = torch.zeros(layout.num_texels, device=layout.heights.device)
    for view_taps in cache.taps or []:
        taps = view_taps[material]
        if taps is not None:
            usage.index_add_(0, taps.texel, taps.weight.abs())
    ones = torch.ones(*layout.size, 1, device=usage.device, requires_grad=True)
    chain = torch.cat([level.reshape(-1) for level in build_mip_chain(ones)])
    (grad,) = torch.autograd.grad((chain * usage).sum(), ones)
    return grad[..., 0] > 0


def fill_unseen(texture: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """Pull-push fill: unseen texels take the average colour of the nearest seen ones.

    Seen texels are returned unchanged. Pull: average colour and coverage down a pyramid of
    2 x 2 sums; push: every unseen texel takes the value of its parent one level coarser.

    Args:
        texture: ``(h, w, C)`` float texture.
        seen: ``(h, w)`` bool.

    Returns:
        ``(h, w, C)`` texture with every texel defined (if any texel is seen).
    """
    if seen.all() or not seen.any():
        return texture.clone()
    weight = seen.to(texture.dtype)[None, None]
    value = texture.permute(2, 0, 1)[None] * weight
    pyramid = [(value, weight)]
    while pyramid[-1][1].shape[-1] > 1 or pyramid[-1][1].shape[-2] > 1:
        value, weight = pyramid[-1]
        pool = lambda x: torch.nn.functional.avg_pool2d(x, 2, ceil_mode=True) * 4  # noqa: E731
        pyramid.append((pool(value), pool(weight)))
    value, weight = pyramid[-1]
    filled = value / weight.clamp_min(1e-12)
    for value, weight in reversed(pyramid[:-1]):
        parent = torch.nn.functional.interpolate(filled, scale_factor=2, mode="nearest")
        parent = parent[..., : value.shape[-2], : value.shape[-1]]
        own = value / weight.clamp_min(1e-12)
        filled = torch.where(weight > 0, own, parent)
    result = filled[0].permute(1, 2, 0)
    return torch.where(seen[..., None], texture, result)
