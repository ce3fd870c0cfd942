"""The job's lit stage: under protocol 2, ``direct``'s asset trained further through lit views.

``direct`` optimises the base colours through unlit views, cheaply (a pixel is a fixed sum of
texels). Under protocol 2 the job keeps :data:`LIT_SHARE` of the method's time for this stage:
the asset as it would ship (those base colours, the other maps by their class, Toksvig
roughness) goes to :func:`geoscaler.optim.lit.optimize_lit`, which trains the maps only light
shows (normal, metallic-roughness, occlusion; :data:`KEPT` stay). What ships is the best, on
lit Q, near and far views, of the trained maps, that start, the class filters with Lanczos base
colours, and every map resized by Lanczos or by bicubic (protocol 2's baselines).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from geoscaler.clock import Budget, Clock
from geoscaler.mesh import BASE_COLOR, TexturedMesh
from geoscaler.methods import MethodResult, Shipping
from geoscaler.optim.events import Controller
from geoscaler.optim.lit import (
    NOT_AFFORDED,
    TRAINED,
    LitFacts,
    LitRun,
    LitSettings,
    train,
)
from geoscaler.pipeline.shipping import every_map_by, ship_asset
from geoscaler.protocol import Evaluation
from geoscaler.render.lit import (
    EMISSIVE,
    METALLIC_ROUGHNESS,
    NORMAL,
    default_protocol,
    lit_maps,
)
from geoscaler.resize.sizes import SizePlan

LIT_METHODS = ("direct",)
"""Methods whose result the lit stage trains further (their parameters are the texels)."""
LIT_SHARE = 0.5
"""Share of a learned method's time budget kept for the lit stage after it: a lit step costs 4
to 10 times an unlit one, and the unlit steps reach the base colours' largest gains first
(docs/decisions/lit-stage.md)."""
LIT_STEPS = 100
"""Steps of the lit stage where the job has no time budget."""
KEPT = (BASE_COLOR, EMISSIVE)
"""Slots the lit stage leaves as they are: the colours a viewer shows under any light (and
unlit). Trained lit, the base colour learns the protocol's two lights: on the sofa at 4x it
gained 0.19 dB lit and lost 1.0 dB unlit (docs/decisions/lit-stage.md)."""
CLASS_FILTERS = "class filters"
"""The baseline with Lanczos base colours and every other map by its class (Toksvig)."""
EVERY_MAP = ("lanczos", "bicubic")
"""The filters that resize every map as protocol 2's baselines do; the base colours the method
made, with every other map by one of them, are the stage's other starts."""


def lit_stage_applies(mesh: TexturedMesh, name: str, protocol: int) -> bool:
    """Whether method ``name``'s result on ``mesh`` goes through the lit stage: under
    protocol 2, for :data:`LIT_METHODS`, where a material has a normal or metallic-roughness
    map of three or more channels on the UVs lit renders read."""
    if protocol != 2 or name not in LIT_METHODS or default_protocol(mesh) != 2:
        return False
    return any(
        slot in (NORMAL, METALLIC_ROUGHNESS) and pixels.ndim == 3 and pixels.shape[2] >= 3
        for material in mesh.materials
        for slot, pixels in lit_maps(material).items()
    )


def lit_stage_price(
    mesh: TexturedMesh,
    plan: SizePlan,
    lanczos: MethodResult | None,
    clock: Clock,
    device: str | None,
    evaluation: Evaluation | None = None,
    seed: int = 0,
    steps: int | None = None,
) -> LitRun:
    """The lit stage, priced before the method runs (:meth:`~geoscaler.optim.lit.LitRun.price`,
    on ``clock``: one lit view cached and one score timed, the rest priced from them; not
    priced where it would train nothing) on the class filters' asset in place of the method's
    result (the same maps, sizes and baselines). :func:`train_lit` trains this run, its view
    and its price kept, from the method's result."""
    baselines = _baselines(mesh, plan, lanczos)
    textures = lanczos.textures if lanczos else None
    start, others = _starts(mesh, plan, textures, baselines)
    run = LitRun(mesh, start, baselines, _settings(seed, steps), device,
                 evaluation or Evaluation(), others)  # fmt: skip
    if run.maps.values:
        run.price(clock)
    return run


def _settings(seed: int, steps: int | None) -> LitSettings:
    return LitSettings(steps=steps, seed=seed, kept=KEPT)


def _baselines(
    mesh: TexturedMesh, plan: SizePlan, lanczos: MethodResult | None
) -> dict[str, TexturedMesh]:
    """The lit stage's baselines: every map by Lanczos, by bicubic, and the class filters
    where there is a Lanczos result."""
    baselines = {f: every_map_by(mesh, plan, f) for f in EVERY_MAP}
    if lanczos is not None:
        baselines[CLASS_FILTERS] = ship_asset(mesh, plan, lanczos.textures, "lanczos")[0]
    return baselines


def _starts(
    mesh: TexturedMesh,
    plan: SizePlan,
    textures: list | None,
    baselines: dict[str, TexturedMesh],
) -> tuple[TexturedMesh, dict[str, TexturedMesh]]:
    """The lit stage's start (``textures`` as base colours, every other map by its class;
    None: bicubic's) and its other starts (the same base colours, every other map by Lanczos,
    by bicubic: a class's filter is not the best on every asset's lit views)."""
    if textures is None:
        return baselines["bicubic"], {}
    others = {f: _with_maps_of(mesh, plan, textures, baselines[f]) for f in EVERY_MAP}
    return ship_asset(mesh, plan, textures, "direct")[0], others


def _with_maps_of(
    mesh: TexturedMesh, plan: SizePlan, textures: list, other: TexturedMesh
) -> TexturedMesh:
    """``mesh`` as it ships with ``textures`` as base colours and every other map as
    ``other`` (``mesh`` with every map resized by one filter) has it."""
    maps = {
        id(original): (made, "")
        for (original, places), (made, _) in zip(mesh.images(), other.images(), strict=True)
        if places[0][1] != BASE_COLOR
    }
    return ship_asset(mesh, plan, textures, "direct", maps)[0]


def train_lit(
    mesh: TexturedMesh,
    plan: SizePlan,
    name: str,
    result: MethodResult,
    lanczos: MethodResult | None,
    budget: Budget,
    device: str | None,
    seed: int = 0,
    steps: int | None = None,
    controller: Controller | None = None,
    progress: Callable[[int, int], None] | None = None,
    evaluation: Evaluation | None = None,
    stage: LitRun | None = None,
    price: float = 0.0,
) -> MethodResult:
    """``result`` (in the mesh's own layout) after the lit stage: its base colours and the
    maps the stage chose (:attr:`MethodResult.maps`), with :attr:`MethodResult.lit`. Where
    ``budget`` cannot hold the stage's least cost, nothing is done and the facts say so.

    Args:
        mesh: the original asset.
        plan: the size rule of each texture class.
        name: the learned method.
        result: its result, as the job would ship it.
        lanczos: the Lanczos filter's result (the class-filters baseline's base colours; None:
            no such baseline).
        budget: the stage's time (unlimited: :data:`LIT_STEPS` steps).
        device: where it trains.
        seed: seeds the training cameras.
        steps: at most this many steps (the user's ``--steps``, as the method's); None: the
            budget's end, or :data:`LIT_STEPS` without one.
        controller: stops the stage (its best so far ships) or pauses it.
        progress: ``progress(done, total)`` after each step (:func:`optimize_lit`).
        evaluation: the validation views' size (default: the protocol's).
        stage: the stage priced before the method ran (:func:`lit_stage_price`, built with
            the same ``lanczos``, ``seed`` and ``steps``): trained from ``result`` on its
            price and its cached view; None: built here and priced on its first view.
        price: the stage's least cost as priced, or a bound under it
            (:func:`~geoscaler.optim.lit.least_seconds_bound`), before the method ran (0:
            not known): where ``budget`` cannot hold it, nothing is built or priced.
    """
    if budget.limited and not budget.fits(price):
        return replace(result, lit=LitFacts(stopped_by=NOT_AFFORDED, clears_floor=False))
    if stage is None:
        baselines = _baselines(mesh, plan, lanczos)
        start, others = _starts(mesh, plan, result.textures, baselines)
        settings = _settings(seed, steps or (None if budget.limited else LIT_STEPS))
        stage = LitRun(mesh, start, baselines, settings, device, evaluation or Evaluation(),
                       others)  # fmt: skip
    else:
        stage.restart(*_starts(mesh, plan, result.textures, stage.baselines))
    best, facts = train(stage, budget, controller, progress)
    if not facts.validation_scores:  # not run: the maps ship by their class, as unlit
        return replace(result, lit=facts)
    how = {
        TRAINED: "trained through lit views (protocol 2)",
        "start": f"by {facts.start_maps or 'its class'}, chosen on lit views",
    }.get(facts.shipped, f"{facts.shipped} (every map), chosen on lit views")
    maps = {}
    for (original, places), (made, _) in zip(mesh.images(), best.images(), strict=True):
        material, slot = places[0]
        if slot != BASE_COLOR and made is not original:
            maps[id(original)] = (made, how)
    textures = [m.base_color_texture for m in best.materials]
    shipped = {TRAINED: name, "start": result.shipped(name), CLASS_FILTERS: "lanczos"}.get(
        facts.shipped, f"{facts.shipped} (every map)"
    )
    shipping = replace(result.shipping or Shipping(name), shipped=shipped)
    return replace(result, textures=textures, maps=maps, lit=facts, shipping=shipping)
