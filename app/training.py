"""The optimisation as the app runs it: on a worker thread, observable from the UI thread.

The worker runs :func:`geoscaler.pipeline.job.downsample` -- the CLI's job -- with a
:class:`~geoscaler.optim.loop.Controller` for pause/resume/stop and a
:class:`~geoscaler.pipeline.job.JobObserver` that records the caching, bicubic's score on Q (the
gain's zero, scored once the validation views are in), the loss and validation PSNR and, a few times
a second, pulls the current texture (and UVs) with ``ProgressEvent.candidate``. The UI thread only
reads :class:`TrainingState` under its lock.

On 2 cores the worker runs torch on one thread (``torch.set_num_threads(1)``, process-wide), so
the UI thread and the GL driver keep the other core. While the user drags the camera the worker
holds back (:meth:`Training.user_moved`): after each step it sleeps as long as the step took,
so the UI, the GL driver's threads and the X server get the CPU half the time. It runs at the
priority of the app: an OS priority would also yield to every other busy process, and a busy
neighbour would then stop the optimiser instead of slowing it. The
interpreter hands the GIL over every 0.5 ms instead of 5 ms, so the UI thread waits less for
it between the worker's torch calls.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from geoscaler.clock import WALL_CLOCK
from geoscaler.color import linear_to_texture, quantize_linear
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import default_steps, is_learned
from geoscaler.optim.events import Controller, ProgressEvent
from geoscaler.pipeline.arguments import (
    DEFAULT_TIME_BUDGET,
    check_method,
    check_scale,
    method_options,
)
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.pipeline.job import Downsampled, JobObserver, checked_output_sizes, downsample
from geoscaler.protocol import GAIN_REFERENCE, PROTOCOL_EVALUATION, Evaluation
from geoscaler.render.metrics import evaluate
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture
from geoscaler.render.views import ViewSet
from geoscaler.uv.uvmodes import JOB_UV_MODE

from .gl_renderer import srgb_mip_chain

SNAPSHOT_INTERVAL = 0.5
"""Seconds between live texture snapshots sent to the UI (each costs the worker a texture
conversion and a mip chain, about 0.1 s for 1024 x 1024 on one core)."""
TORCH_THREADS = 1
GIL_SWITCH_INTERVAL = 0.0005
"""Seconds (``sys.setswitchinterval``), a tenth of the interpreter's 5 ms: the UI thread waits
less for the GIL between the worker's torch calls, so frames orbiting while training come a
little sooner (``benchmarks/bench_app.py``, mode ``orbit``)."""
USER_MOVE_HOLD = 0.3
"""Seconds after the camera last moved during which the worker holds back after each step."""
MAX_HOLD = 1.0
"""Seconds the worker sleeps at most after one step while the user moves the camera."""
SSIM_VIEWS = 6
"""Validation views on which the worker also measures SSIM-fg at each validation (the loop
itself validates on PSNR-fg only); a subset keeps it to about a second."""


@dataclass
class TrainingSettings:
    """What to run; the defaults are the CLI's.

    Attributes:
        method: a registered method name (:func:`geoscaler.methods.method_names`).
        scale: reduction factor per side.
        steps: step limit of learned methods (None: the method's default, :meth:`step_limit`).
        time_budget: seconds a learned method may spend, view caching included (default: the
            CLI's, :data:`geoscaler.pipeline.arguments.DEFAULT_TIME_BUDGET`; None: no limit).
        evaluation: image size and views of the torch renders (protocol 1; tests use less).
        optimize: ``OptimizeConfig`` overrides for learned methods (tests use a small pool).
        renderer: what learned methods train through: ``"exact"`` or ``"soft"`` (the paper's
            soft rasteriser); validation is exact either way.
        uv: ``direct``'s UV layout through the exact renderer: ``"keep"``, ``"repack"`` or
            ``"auto"`` (``--uv``; default as ``downsample``'s, :data:`JOB_UV_MODE`); the soft
            renderer trains in the mesh's own layout.
    """

    method: str = "direct"
    scale: int = 4
    steps: int | None = None
    time_budget: float | None = DEFAULT_TIME_BUDGET
    evaluation: Evaluation = PROTOCOL_EVALUATION
    optimize: dict[str, Any] = field(default_factory=dict)
    renderer: str = "exact"
    uv: str = JOB_UV_MODE

    def step_limit(self) -> int | None:
        """The steps the run will stop at (unless its time budget ends it first); None when
        the method's default is not known here."""
        return self.steps or default_steps(self.method, {"optimize": self.optimize})


@dataclass
class TrainingState:
    """What the UI shows; written by the worker, read under :attr:`Training.lock`."""

    phase: str = "idle"
    step: int = 0
    total_steps: int = 0
    caching: tuple[int, int] = (0, 0)
    steps: list[float] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    losses: list[float] = field(default_factory=list)
    validation_steps: list[float] = field(default_factory=list)
    validation_times: list[float] = field(default_factory=list)
    validation_psnr: list[float] = field(default_factory=list)
    validation_ssim: list[float] = field(default_factory=list)
    bicubic_psnr: float = math.nan
    best_psnr: float = -math.inf
    textures: list[np.ndarray | None] | None = None
    uvs: np.ndarray | None = None  # the live candidate's UVs (None: the mesh's own)
    chains: list[list[np.ndarray] | None] | None = None
    texture_version: int = 0
    result: Downsampled | None = None
    error: str | None = None

    @property
    def gain(self) -> float:
        """Best validation PSNR-fg minus bicubic's, dB (nan until both are known)."""
        if not (math.isfinite(self.best_psnr) and math.isfinite(self.bicubic_psnr)):
            return math.nan
        return self.best_psnr - self.bicubic_psnr


class Training:
    """One run of a method on a mesh, on a daemon thread.

    Args:
        mesh: the mesh (read only).
        settings: what to run.

    Raises:
        GeoscalerError: an unknown method, a bad scale, steps or time budget.
    """

    def __init__(self, mesh: TexturedMesh, settings: TrainingSettings):
        check_method(settings.method)
        checked_output_sizes(mesh, check_scale(settings.scale))
        self.mesh = mesh
        self.settings = settings
        loop = dict(settings.optimize)
        if settings.renderer != "exact":
            loop["training_renderer"] = settings.renderer
        extra: dict[str, Any] = {"optimize": loop} if loop else {}
        uv = settings.uv if settings.renderer == "exact" else "keep"
        if uv != "keep" and settings.method == "direct":
            extra["uv"] = uv
        # No default budget here: None is the user's "no limit". A filter has no budget (the
        # field is not shown for it), as the CLI gives it none unless asked.
        budget = settings.time_budget if is_learned(settings.method) else None
        self.options = method_options([settings.method], "cpu", 0, settings.steps, budget, extra)
        self.q: ViewSet | None = None
        self.controller = Controller()
        self.lock = threading.Lock()
        self.state = TrainingState(total_steps=settings.step_limit() or 0)
        self.thread = threading.Thread(target=self._run, name="geoscaler-training", daemon=True)
        self.started = 0.0
        self.seconds = 0.0  # wall time of the whole run, set when it ends
        self._last_snapshot = 0.0
        self._user_moved_at = -math.inf  # WALL_CLOCK.now() of the camera's last move
        self._last_step_at = 0.0  # the worker's WALL_CLOCK.now() after its last step

    def start(self) -> None:
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        self.started = WALL_CLOCK.now()
        self.thread.start()

    def pause(self) -> None:
        self.controller.pause()
        self._set(phase="paused")

    def resume(self) -> None:
        self.controller.resume()
        self._set(phase="optimising")

    def stop(self) -> None:
        """Ask the method to stop; the best result so far is still scored and kept."""
        self.controller.stop()

    def user_moved(self) -> None:
        """The user moved the camera (UI thread): for :data:`USER_MOVE_HOLD` seconds the
        worker sleeps after each step as long as the step took (:meth:`hold_back`)."""
        self._user_moved_at = WALL_CLOCK.now()

    def hold_back(self, now: float) -> float:
        """Seconds the worker should sleep after a step that ended at ``now``: as long as the
        step took (at most :data:`MAX_HOLD`) while the user moves the camera, else 0."""
        step_seconds = now - self._last_step_at
        held = now - self._user_moved_at <= USER_MOVE_HOLD
        pause = min(step_seconds, MAX_HOLD) if held else 0.0
        self._last_step_at = now + pause  # the next step starts after the pause
        return pause

    @property
    def running(self) -> bool:
        return self.thread.is_alive()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the worker; True when it has finished."""
        self.thread.join(timeout)
        return not self.thread.is_alive()

    def read(self) -> TrainingState:
        """A shallow copy of the state, consistent at one instant (lists are copied)."""
        with self.lock:
            state = TrainingState(**self.state.__dict__)
            for name in (
                "steps",
                "times",
                "losses",
                "validation_steps",
                "validation_times",
                "validation_psnr",
                "validation_ssim",
            ):
                setattr(state, name, list(getattr(state, name)))
            return state

    def _set(self, **values: Any) -> None:
        with self.lock:
            for name, value in values.items():
                setattr(self.state, name, value)

    def _run(self) -> None:
        torch.set_num_threads(TORCH_THREADS)
        try:
            self._set(phase="caching validation views")
            settings = self.settings
            renderer = Renderer(self.mesh, "cpu", product_evaluation(settings.evaluation))
            done = downsample(
                self.mesh,
                settings.scale,
                settings.method,
                self.options,
                renderer,
                _Observer(self),
                self.controller,
            )
            rows = {row["method"]: row for row in done.rows}
            best = rows[settings.method]["psnr_fg"]
            self.seconds = WALL_CLOCK.now() - self.started
            textures = [None if t is None else t[..., :3] for t in done.result.textures]
            self._set(
                result=done,
                best_psnr=best,
                phase="done",
                textures=textures,
                chains=[None if t is None else srgb_mip_chain(t) for t in textures],
                texture_version=self.state.texture_version + 1,
            )
        except Exception as error:  # shown in the UI; the app keeps running
            self.seconds = WALL_CLOCK.now() - self.started
            self._set(phase="failed", error=f"{type(error).__name__}: {error}")

    @torch.no_grad()
    def _ssim(self, textures: list[torch.Tensor | None], uvs: torch.Tensor | None) -> float:
        """Mean SSIM-fg of 8-bit-quantised ``textures`` (on ``uvs``, None: the mesh's) over
        the first :data:`SSIM_VIEWS` of Q."""
        q = self.q
        if q is None:
            return math.nan
        views = range(min(SSIM_VIEWS, len(q)))
        mips = [None if t is None else MipTexture(quantize_linear(t)) for t in textures]
        images = q.render(mips, uvs, views=views)
        scores = evaluate(images, *q.stacked(len(views)))
        return float(scores["ssim_fg"].mean())

    def _on_event(self, event: ProgressEvent) -> None:
        """Take one progress event of the job into the state the UI draws."""
        if event.phase == "caching":
            self._set(caching=(event.done, event.total))
            return
        if event.phase == "baselines" and GAIN_REFERENCE in event.baselines:
            self._set(bicubic_psnr=event.baselines[GAIN_REFERENCE]["Q"])
            return
        with self.lock:
            self._record(event)
        now = WALL_CLOCK.now()
        if event.phase == "step":
            time.sleep(self.hold_back(now))
        live = now - self._last_snapshot > SNAPSHOT_INTERVAL
        if event.candidate is None or not (live or event.phase == "validation"):
            return
        self._take_candidate(event, now, live)

    def _record(self, event: ProgressEvent) -> None:
        """The event's step, best PSNR, phase and curve points into the state (lock held)."""
        state = self.state
        state.step, state.total_steps = event.step, event.total_steps
        if math.isfinite(event.best_psnr):
            state.best_psnr = event.best_psnr
        if event.phase == "step":
            if not self.controller.paused:
                state.phase = "optimising"
            state.steps.append(event.step)
            state.times.append(event.elapsed)
            state.losses.append(event.loss)
        elif event.phase == "validation" and event.validation_psnr is not None:
            state.validation_steps.append(event.step)
            state.validation_times.append(event.elapsed)
            state.validation_psnr.append(event.validation_psnr)
        elif event.phase == "done":
            state.phase = "scoring on the validation views"

    def _take_candidate(self, event: ProgressEvent, now: float, live: bool) -> None:
        """Score the event's candidate (SSIM, at a validation) and show it when ``live``."""
        linear, uvs = event.candidate()
        if event.phase == "validation":
            ssim = self._ssim(linear, uvs)
            with self.lock:
                self.state.validation_ssim.append(ssim)
        if live:
            self._snapshot(linear, uvs, now)

    def _snapshot(
        self, linear: list[torch.Tensor | None], uvs: torch.Tensor | None, now: float
    ) -> None:
        """Make the candidate's textures and UVs the ones the views draw (a new snapshot)."""
        self._last_snapshot = now
        textures = [None if t is None else linear_to_texture(t) for t in linear]
        chains = [None if t is None else srgb_mip_chain(t) for t in textures]
        moved = None if uvs is None else uvs.cpu().numpy().astype(np.float32)
        with self.lock:
            self.state.textures, self.state.chains = textures, chains
            self.state.uvs = moved
            self.state.texture_version += 1


class _Observer(JobObserver):
    """Feeds a :class:`Training`'s state from its job."""

    def __init__(self, training: Training):
        self.training = training

    def stage(self, what: str, done: int, total: int) -> None:
        if what == "caching Q":
            self.training._set(caching=(done, total))

    def views_cached(self, distance: float, views: ViewSet) -> None:
        self.training.q = views

    def scored(self, row: dict[str, Any]) -> None:
        if row["method"] == GAIN_REFERENCE:
            self.training._set(bicubic_psnr=row["psnr_fg"])

    def method_started(self, name: str, scale: int, time_budget: float | None) -> None:
        if name == self.training.settings.method:
            learned = is_learned(name)
            self.training._set(phase="caching training views" if learned else f"running {name}")

    def on_event(self, event: ProgressEvent) -> None:
        self.training._on_event(event)
