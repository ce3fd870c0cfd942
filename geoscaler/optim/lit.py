"""Every lit map of a PBR asset trained together through protocol 2's lit renders.

The start is an asset as it would ship (each map at its size, the mesh's own UVs: ``direct``'s
base colours with the class filters and Toksvig roughness for the rest); each distinct lit
image of three or more channels (but those of slots the caller keeps) becomes one trainable
``(h, w, 3)`` tensor of its stored values in [0, 1] (:class:`LitMaps`): sRGB-encoded colour for
base colour and emission (a step then moves dark and bright texels by similar visible amounts,
as ``direct``'s texels), the linear values of data maps, and the encoded vectors of normal
maps, kept unit and facing out of the surface after every step. Adam minimises the mean
squared error of lit sRGB renders of training views against the full-resolution original's
(:class:`~geoscaler.render.lit_views.LitViews`).

Candidates are validated as they ship (8-bit) on lit Q, near and far sets; the floor is the
best of the caller's *baselines* on each set (filters' assets), and what :func:`optimize_lit`
returns is what :class:`~geoscaler.optim.floor.Floor` ranks first of the trained maps, the
start and the baselines, so the result is never below the best baseline on any set beyond the
floor's noise margin, whatever the training did. A validated candidate below the best sends the maps
back to the best at a lower rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from geoscaler.clock import Budget, Clock
from geoscaler.color import srgb_to_linear
from geoscaler.mesh import TexturedMesh
from geoscaler.optim.adamw import AdamW
from geoscaler.optim.events import Controller
from geoscaler.optim.floor import Floor, Scores
from geoscaler.optim.loop import TRAINING_RANGES, VIEW_MEMORY
from geoscaler.optim.validation_views import SET_NAMES, validation_set_cameras
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera, sample_training_cameras
from geoscaler.render.lit import (
    NORMAL,
    SRGB_SLOTS,
    LitMaterial,
    LitScene,
    lit_factors,
    lit_maps,
    lit_materials,
)
from geoscaler.render.lit_views import LitViews, map_sizes
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture

TRAINED = "lit"
"""What :class:`LitFacts` calls the trained maps (beside the baselines' names)."""
LEAST_STEPS = 5
"""Steps the budget must hold besides the validation's set-up for the loop to run at all."""
NOT_AFFORDED = "the time left cannot hold the lit views' set-up and a few steps"
"""``stopped_by`` of a run that did not start: the start ships, not validated lit."""


@dataclass(frozen=True)
class LitSettings:
    """How :func:`optimize_lit` trains.

    Attributes:
        lr: Adam's learning rate, in the maps' stored [0, 1] units (0.002: half a code a step).
        views_per_step: training views whose mean loss is one step's.
        pool_views: training cameras, cached while the loop runs: with fewer the maps fit the
            training views' lights at the cost of others' (the validation turns back sooner).
        cached_per_step: training views cached after each step until the pool is complete.
        training_share: side of the training views as a share of the validation views' (384
            pixels at the protocol's 512, 2 x 2 samples a pixel both): a lit view holds every
            sample's taps, frame and view vector (about 40 MB at 512 on a mesh filling a
            third of the image); at 384 a view costs half and the validation gains matched
            512's on the development meshes tried (docs/decisions/lit-stage.md).
        view_memory: bytes the training pool and the validation sets may hold together: past
            them the pool stops growing (None: no limit).
        kept: slots whose maps are not trained (:class:`LitMaps`).
        validation_views: views of each of the Q, near and far sets.
        validate_every: steps between validations (and the last step).
        backtrack: factor on the rate when a validated candidate ranks below the best.
        caching_share: share of the time left as training begins after which the pool stops
            growing.
        steps: at most this many steps (None: the budget alone stops the loop).
        seed: seeds the training cameras.
    """

    lr: float = 0.002
    views_per_step: int = 4
    pool_views: int = 48
    cached_per_step: int = 2
    training_share: float = 0.75
    view_memory: int | None = VIEW_MEMORY
    kept: tuple[str, ...] = ()
    validation_views: int = 8
    validate_every: int = 10
    backtrack: float = 0.5
    caching_share: float = 0.4
    steps: int | None = None
    seed: int = 0


@dataclass
class LitFacts:
    """What :func:`optimize_lit` did.

    Attributes:
        steps: training steps taken; best_step: the step of the best trained candidate (0:
            the start).
        shipped: what the returned asset is: :data:`TRAINED`, ``"start"`` or a baseline's name.
        validation_scores: set name -> mean lit PSNR-fg (dB) of what is returned.
        baseline_scores: name -> its scores per set (the start among them).
        clears_floor: the returned asset is no worse than the best baseline on every set.
        stopped_by: ``"time budget"``, ``"steps"``, ``"stopped"`` (the controller),
            ``"nothing to train"`` or :data:`NOT_AFFORDED` (then nothing was validated lit:
            the start is returned, with no scores).
        training_views: training views cached; validation_views: views of each set.
        backtracks: times the maps went back to the best.
        start_maps: the other start trained from, where it ranked above the given one
            (:class:`LitRun`'s ``other_starts``); None: the given one.
        other_starts_left_out: the other starts were not scored: the budget held the run's
            least cost but not their scoring on top.
    """

    steps: int = 0
    best_step: int = 0
    shipped: str = "start"
    validation_scores: dict[str, float] = field(default_factory=dict)
    baseline_scores: dict[str, dict[str, float]] = field(default_factory=dict)
    clears_floor: bool = True
    stopped_by: str = "steps"
    training_views: int = 0
    validation_views: int = 0
    backtracks: int = 0
    start_maps: str | None = None
    other_starts_left_out: bool = False


@dataclass(frozen=True)
class LitPrice:
    """What a :class:`LitRun` costs at least, in seconds, priced from its first validation view
    (:meth:`LitRun.price`).

    Attributes:
        least: caching every validation view, scoring the start and the baselines on each,
            and :data:`LEAST_STEPS` steps (:func:`least_seconds`).
        other_starts: scoring the other starts on every validation view: the run leaves them
            out where its time holds ``least`` but not both.
    """

    least: float
    other_starts: float


class LitMaps:
    """The lit images of an asset as trainable tensors (see the module's docstring).

    Args:
        asset: the start; its lit images of 3 or more channels are trained (grey ones kept).
        device: where the tensors live.
        kept: slots whose images stay as they are (an image another slot trains is trained).
    """

    def __init__(
        self, asset: TexturedMesh, device: torch.device | str, kept: Sequence[str] = ()
    ):
        self.start = asset
        self.values: dict[int, torch.Tensor] = {}  # id(image) -> (h, w, 3) stored values
        self.images: dict[int, np.ndarray] = {}
        self.colour: set[int] = set()
        self.normal: set[int] = set()
        for material in asset.materials:
            for slot, pixels in lit_maps(material).items():
                if pixels.ndim != 3 or pixels.shape[2] < 3 or slot in kept:
                    continue
                key = id(pixels)
                if key not in self.values:
                    stored = torch.from_numpy(pixels[..., :3].astype(np.float32) / 255.0)
                    self.values[key] = stored.to(device).requires_grad_(True)
                    self.images[key] = pixels
                if slot in SRGB_SLOTS:
                    self.colour.add(key)
                elif slot == NORMAL:
                    self.normal.add(key)
        self.fixed = lit_materials(asset, device, encoded=False)

    def parameters(self) -> list[torch.Tensor]:
        return list(self.values.values())

    def materials(self) -> list[LitMaterial]:
        """The asset's materials with the tensors' mip chains (differentiable)."""
        chains = {}
        for key, values in self.values.items():
            chains[key] = MipTexture(srgb_to_linear(values) if key in self.colour else values)
        materials = []
        for material, fixed in zip(self.start.materials, self.fixed, strict=True):
            maps = dict(fixed.maps)
            for slot, pixels in lit_maps(material).items():
                maps[slot] = chains.get(id(pixels), maps.get(slot))
            materials.append(LitMaterial(maps, **lit_factors(material)))
        return materials

    @torch.no_grad()
    def project(self) -> None:
        """Keep every value in [0, 1] and every normal-map vector unit with ``z >= 0``."""
        for key, values in self.values.items():
            if key in self.normal:
                vector = 2 * values - 1
                vector[..., 2].clamp_(min=0.0)
                length = vector.norm(dim=-1, keepdim=True)
                flat = torch.tensor([0.0, 0.0, 1.0], dtype=values.dtype, device=values.device)
                vector = torch.where(length > 1e-6, vector / length.clamp_min(1e-6), flat)
                values.copy_((vector + 1) / 2)
            values.clamp_(0.0, 1.0)

    @torch.no_grad()
    def asset(self) -> TexturedMesh:
        """The start asset with every trained image written as 8 bits (alpha kept)."""
        replacements = {}
        for key, values in self.values.items():
            out = self.images[key].copy()
            out[..., :3] = values.mul(255).round().to(torch.uint8).cpu().numpy()
            replacements[key] = out
        return self.start.with_images(replacements)

    @torch.no_grad()
    def restore(self, asset: TexturedMesh) -> None:
        """Set the tensors to the images of ``asset``, an :meth:`asset` of these maps."""
        by_place = {}
        for pixels, places in asset.images():
            by_place[places[0]] = pixels
        for pixels, places in self.start.images():
            if id(pixels) in self.values:
                stored = by_place[places[0]][..., :3].astype(np.float32) / 255.0
                self.values[id(pixels)].copy_(torch.from_numpy(stored))


def least_seconds(
    view_seconds: float, score_seconds: float, views: float, candidates: int, settings: LitSettings
) -> float:
    """The least a lit run costs (seconds): caching ``views`` validation views and scoring
    ``candidates`` on each, then :data:`LEAST_STEPS` steps, each priced as a validation view
    per training view (``view_seconds`` a view, ``score_seconds`` a candidate's score on
    one; ``views`` may count each view by its screen share, :func:`screen_shares`)."""
    setup = views * (view_seconds + candidates * score_seconds)
    return setup + LEAST_STEPS * settings.views_per_step * view_seconds


def screen_shares(cameras: Sequence[Camera], timed: Camera) -> float:
    """``cameras`` counted by the screen the object fills in each against the ``timed`` one's,
    ``(timed.distance / distance)^2``: caching and scoring a view cost about as many samples
    as it covers. On ph_wooden_bookshelf_worn at 4x a near view (1.5) took 0.55 to 0.91 s to
    cache, a Q view (2.4) 0.25 to 0.46 and a far one (4.0) 0.12 to 0.20: the square gives near
    views 2.6 Q views and far ones 0.36, erring high where most of the time goes."""
    return sum((timed.distance / camera.distance) ** 2 for camera in cameras)


def least_seconds_bound(
    view_seconds: float, evaluation: Evaluation, settings: LitSettings = LitSettings()
) -> float:
    """A bound under the :meth:`LitRun.price` of a run on ``evaluation``'s views where no lit
    view costs less than ``view_seconds`` for the first Q camera (the unlit view of that
    camera: a lit one rasterises the same samples, renders the original's every map and taps
    more maps): its views and steps, the scoring left out."""
    sets = lit_set_cameras(evaluation, settings.validation_views)
    cameras = [camera for name in SET_NAMES for camera in sets[name]]
    return least_seconds(view_seconds, 0.0, screen_shares(cameras, sets["Q"][0]), 0, settings)


def lit_set_cameras(evaluation: Evaluation, count: int) -> dict[str, list[Camera]]:
    """The lit Q, near and far sets' cameras: the unlit loop's
    (:func:`~geoscaler.optim.validation_views.validation_set_cameras`), ``count`` guards at
    each distance and Q's first ``count`` in its spread order."""
    cameras = validation_set_cameras(evaluation, count)
    return {name: cameras[name][:count] for name in SET_NAMES}


def validation_sets(
    scene: LitScene,
    reference: Sequence[LitMaterial],
    sizes: Sequence[set[tuple[int, int]]],
    count: int,
) -> dict[str, LitViews]:
    """The lit Q, near and far sets (:func:`lit_set_cameras`), none cached yet."""
    cameras = lit_set_cameras(scene.renderer.evaluation, count)
    return {name: LitViews(scene, reference, sizes, cameras[name]) for name in SET_NAMES}


class LitRun:
    """One run of :func:`optimize_lit`: its views, maps, optimiser, floor and best so far."""

    def __init__(
        self,
        original: TexturedMesh,
        start: TexturedMesh,
        baselines: Mapping[str, TexturedMesh],
        settings: LitSettings,
        device: torch.device | str | None,
        evaluation: Evaluation,
        other_starts: Mapping[str, TexturedMesh] | None = None,
    ):
        """``evaluation``: the validation views' size and protocol views; originals are read
        uncapped (its reference cap is ignored). ``other_starts``: name -> ``start`` with
        other trained maps (the same sizes); training starts from the one that ranks first
        on the validation (:meth:`begin`)."""
        evaluation = replace(evaluation, reference_max_size=None)
        self.settings = settings
        self.other_starts = dict(other_starts or {})
        self.priced: LitPrice | None = None
        renderer = Renderer(original, device, evaluation)
        self.device = renderer.device
        scene = LitScene(renderer)
        reference = lit_materials(original, self.device)
        self.train_from(start)
        sizes = map_sizes(self.maps.fixed)
        self.sets = validation_sets(scene, reference, sizes, settings.validation_views)
        self.baselines = dict(baselines)
        self.candidates = {"start": start, **baselines}
        self.scores: dict[str, Scores] = {}
        self.floor = Floor({}, SET_NAMES)
        self.trained, self.trained_rank = start, (-math.inf, -math.inf)
        cameras = sample_training_cameras(settings.pool_views, settings.seed, TRAINING_RANGES)
        side = max(1, round(settings.training_share * evaluation.image_size))
        training = replace(evaluation, image_size=side)
        training_scene = LitScene(Renderer(original, device, training))
        self.pool = LitViews(training_scene, reference, sizes, cameras)
        self.facts = LitFacts(validation_views=settings.validation_views)

    def price(self, clock: Clock) -> LitPrice:
        """What this run costs (:class:`LitPrice`), on ``clock``: the first call caches the
        first Q view and times it and the start's score there, every other view priced from
        them by its screen share (:func:`screen_shares`); later calls return that price, so
        whoever decides on it and the run itself read the same one."""
        if self.priced is not None:
            return self.priced
        q = self.sets["Q"]
        began = clock.now()
        q.cache_next()
        view_seconds = clock.now() - began
        began = clock.now()
        q.psnr(lit_materials(self.candidates["start"], self.device, encoded=False), count=1)
        score_seconds = clock.now() - began
        cameras = [camera for views in self.sets.values() for camera in views.cameras]
        views = screen_shares(cameras, q.cameras[0])
        scored = len(self.candidates)
        least = least_seconds(view_seconds, score_seconds, views, scored, self.settings)
        others = views * score_seconds * len(self.other_starts)
        self.priced = LitPrice(least, others)
        return self.priced

    def affords(self, budget: Budget) -> bool:
        """Whether ``budget`` holds the least this run costs (:meth:`price`; any run without
        a limit); where it does not hold the other starts' scoring on top, they are left out
        and the given start is trained."""
        if not budget.limited:
            return True
        price, left = self.price(budget.clock), budget.left()
        if self.other_starts and price.least + price.other_starts > left:
            self.other_starts, self.facts.other_starts_left_out = {}, True
        return price.least <= left

    def restart(self, start: TexturedMesh, other_starts: Mapping[str, TexturedMesh]) -> None:
        """Train from ``start`` (maps of the sizes this run was built for) and weigh
        ``other_starts`` in place of the ones given so far; the views cached and the price
        stay."""
        self.candidates["start"] = start
        self.other_starts = dict(other_starts)
        self.trained = start
        self.train_from(start)

    def begin(self) -> None:
        """Cache the validation views, score the start and the baselines, set the floor, and
        start from the best-ranked of the start and the other starts."""
        for views in self.sets.values():
            while views.cache_next():
                pass
        self.scores = {name: self.score(asset) for name, asset in self.candidates.items()}
        self.floor = Floor({k: v for k, v in self.scores.items() if k != "start"}, SET_NAMES)
        self._choose_start()
        self.trained_rank = self.floor.rank(self.scores["start"])
        self.facts.baseline_scores = {name: dict(s) for name, s in self.scores.items()}

    def _choose_start(self) -> None:
        """Score every other start; the one that ranks first by the floor's order
        (:meth:`~geoscaler.optim.floor.Floor.rank`, the order what ships is chosen in), where
        it ranks above the start, becomes the start (its maps the trained parameters, a new
        optimiser over them)."""
        rank = self.floor.rank(self.scores["start"])
        for name, asset in self.other_starts.items():
            scores = self.score(asset)
            if (ranked := self.floor.rank(scores)) > rank:
                rank, self.facts.start_maps = ranked, name
                self.candidates["start"], self.scores["start"] = asset, scores
        if self.facts.start_maps is not None:
            self.trained = self.candidates["start"]  # what a backtrack goes back to
            self.train_from(self.trained)

    def train_from(self, start: TexturedMesh) -> None:
        """Make ``start``'s lit maps the trained parameters, with a new optimiser over them."""
        self.maps = LitMaps(start, self.device, self.settings.kept)
        self.optimiser = AdamW(self.maps.parameters(), lr=self.settings.lr, weight_decay=0.0)

    def memory_left(self) -> bool:
        """Whether the views hold less than ``settings.view_memory``."""
        limit = self.settings.view_memory
        held = self.pool.nbytes + sum(views.nbytes for views in self.sets.values())
        return limit is None or held < limit

    def score(self, asset: TexturedMesh) -> Scores:
        """The lit PSNR-fg of an 8-bit asset on every set, per view and mean."""
        materials = lit_materials(asset, self.device, encoded=False)
        per_view = {name: views.psnr(materials) for name, views in self.sets.items()}
        return Scores({name: float(np.nanmean(v)) for name, v in per_view.items()}, per_view)

    def step(self, cache: bool) -> None:
        """One Adam step on the next training views (caching one more view if ``cache``)."""
        settings, pool = self.settings, self.pool
        while not pool.complete and len(pool) < settings.views_per_step:
            pool.cache_next()
        for _ in range(settings.cached_per_step if cache and self.memory_left() else 0):
            pool.cache_next()
        self.optimiser.zero_grad()
        materials = self.maps.materials()
        first = self.facts.steps * settings.views_per_step
        chosen = [(first + k) % len(pool) for k in range(settings.views_per_step)]
        loss = sum(pool.loss(i, materials) for i in chosen) / len(chosen)
        loss.backward()
        self.optimiser.step()
        self.maps.project()
        self.facts.steps += 1

    def validate(self) -> None:
        """Score the maps as they ship; keep them if they rank above the best trained so far,
        else go back to that best at a lower rate."""
        asset = self.maps.asset()
        scores = self.score(asset)
        rank = self.floor.rank(scores)
        if rank > self.trained_rank:
            self.trained, self.trained_rank = asset, rank
            self.scores[TRAINED], self.facts.best_step = scores, self.facts.steps
            return
        self.maps.restore(self.trained)
        self.facts.backtracks += 1
        self.optimiser.lr *= self.settings.backtrack

    def best(self) -> tuple[TexturedMesh, LitFacts]:
        """What ranks first of the trained maps, the start and the baselines."""
        name = max(self.scores, key=lambda n: self.floor.rank(self.scores[n]))
        facts = self.facts
        facts.training_views, facts.shipped = len(self.pool), name
        facts.validation_scores = dict(self.scores[name])
        facts.clears_floor = self.floor.shortfall(self.scores[name]) == 0.0
        return self.trained if name == TRAINED else self.candidates[name], facts


def optimize_lit(
    original: TexturedMesh,
    start: TexturedMesh,
    baselines: Mapping[str, TexturedMesh],
    budget: Budget,
    settings: LitSettings = LitSettings(),
    device: torch.device | str | None = None,
    controller: Controller | None = None,
    progress: Callable[[int, int], None] | None = None,
    evaluation: Evaluation | None = None,
    other_starts: Mapping[str, TexturedMesh] | None = None,
) -> tuple[TexturedMesh, LitFacts]:
    """Train every lit map of ``start`` (the original's geometry and UVs, smaller maps of the
    same sizes as every baseline's) through lit views until ``budget`` or ``settings.steps``
    runs out, or ``controller`` stops it; return the best of the trained maps, the start and
    the ``baselines`` by the floor's rank, with what was done.

    Each step is timed, and so is each validation; a step is taken only where the budget holds
    it and a validation after it (half as much again), and the last step before the budget or
    the step limit ends validates. ``progress(done, total)`` follows each step: seconds of the
    budget (steps without one). ``evaluation``: the validation views' size and protocol views
    (default: the protocol's, originals uncapped; its reference cap is ignored).
    ``other_starts``: ``start`` with other trained maps; training starts from the best-ranked
    (:class:`LitRun`).
    """
    evaluation = evaluation or Evaluation()
    run = LitRun(original, start, baselines, settings, device, evaluation, other_starts)
    return train(run, budget, controller, progress)


def train(
    run: LitRun,
    budget: Budget,
    controller: Controller | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[TexturedMesh, LitFacts]:
    """:func:`optimize_lit` on a built run (one priced before, :meth:`LitRun.price`, keeps
    its price and its cached view)."""
    clock, settings, facts = budget.clock, run.settings, run.facts
    if not run.maps.values:
        facts.stopped_by, facts.clears_floor = "nothing to train", False
        return run.candidates["start"], facts
    if not run.affords(budget):
        facts.stopped_by, facts.clears_floor = NOT_AFFORDED, False
        return run.candidates["start"], facts
    run.begin()
    step_seconds = validation_seconds = 0.0
    caching_end = clock.now() + settings.caching_share * budget.left()
    while settings.steps is None or facts.steps < settings.steps:
        if controller is not None:
            controller.wait_while_paused()
            if controller.stopped:
                facts.stopped_by = "stopped"
                break
        if not budget.fits(step_seconds + 1.5 * validation_seconds):
            facts.stopped_by = "time budget"
            break
        began = clock.now()
        run.step(cache=began < caching_end)
        step_seconds = max(step_seconds, clock.now() - began)
        last = settings.steps is not None and facts.steps >= settings.steps
        last = last or not budget.fits(2 * step_seconds + 1.5 * validation_seconds)
        if facts.steps % settings.validate_every == 0 or last:
            began = clock.now()
            run.validate()
            validation_seconds = clock.now() - began
        if progress is not None:
            if budget.limited:
                progress(round(budget.elapsed()), round(budget.end - budget.start))
            else:
                progress(facts.steps, settings.steps or facts.steps)
    return run.best()
