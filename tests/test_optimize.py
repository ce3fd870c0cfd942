"""The optimisation loop and method `direct` on a small procedural mesh."""

import gc
import math
import threading
import weakref

import numpy as np
import pytest
import torch
from mesh_support import three_material_demo

import geoscaler.optim.loop as loop_module
from geoscaler.clock import WALL_CLOCK, Budget, Clock, ManualClock
from geoscaler.color import linear_to_srgb, linear_to_texture, texture_to_linear
from geoscaler.methods import MethodOptions, RunContext, run_method
from geoscaler.methods.direct import TexelModel
from geoscaler.methods.learned import loop_config
from geoscaler.optim.events import Controller
from geoscaler.optim.loop import (
    CACHING_PER_STEPPING,
    FINISH_MARGIN,
    METHOD_MEMORY,
    NOTHING_TO_GAIN,
    LoopSetup,
    OptimizeConfig,
    _Best,
    optimize,
    train_step,
)
from geoscaler.optim.losses import rendering_loss, view_loss
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet, training_views
from geoscaler.resize.filters import lanczos, output_sizes, reference_textures

SCALE = 4


@pytest.fixture(scope="module")
def scene():
    """The mesh, a 64-pixel renderer and its validation views (every tenth protocol view as
    Q, two near and two far guards), all cached."""
    mesh = demo_mesh(subdivisions=6, texture_size=128)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=64, views=tuple(range(0, 60, 10))))
    views = validation_view_sets(renderer, guard_views=2)
    for view_set in views.values():
        while view_set.cache_next():
            pass
    return mesh, renderer, views


def fresh_validation(scene, baselines=None) -> Validation:
    """A validation of the 32 x 32 output on the scene's views, not yet frozen."""
    mesh, _, views = scene
    return Validation(views, output_sizes(mesh, SCALE), baselines)


def q_psnr(scene, texture: np.ndarray) -> float:
    """PSNR-fg on the scene's Q of an 8-bit texture."""
    return fresh_validation(scene).score([texture], sets=["Q"])["Q"]["psnr_fg"]


def small_config(**overrides) -> OptimizeConfig:
    settings = dict(
        steps=30,
        pool_views=16,
        views_per_step=4,
        lr=0.02,
        ssim_weight=0.0,
        validate_every=10,
        seed=1,
    )
    return OptimizeConfig(**{**settings, **overrides})


def lanczos_model(mesh) -> TexelModel:
    start = lanczos(reference_textures(mesh)[0], SCALE)
    return TexelModel([texture_to_linear(start)])


def run(scene, validation=None, **overrides):
    mesh, renderer, _ = scene
    model = lanczos_model(mesh)
    validation = fresh_validation(scene) if validation is None else validation
    return optimize(renderer, model, small_config(**overrides), validation=validation)


def test_direct_beats_its_lanczos_start_within_a_few_dozen_steps(scene):
    mesh, _, _ = scene
    start = q_psnr(scene, lanczos(reference_textures(mesh)[0], SCALE))
    result = run(scene)
    final = q_psnr(scene, linear_to_texture(result.textures[0]))
    assert result.steps == 30 and result.best_step == 30
    assert final > start + 0.3


def test_the_best_state_is_never_worse_than_the_start(scene):
    mesh, _, _ = scene
    start = q_psnr(scene, lanczos(reference_textures(mesh)[0], SCALE))
    result = run(scene, steps=5, lr=0.5)  # far too large: the steps only hurt
    assert result.best_step == 0
    assert result.best_psnr == pytest.approx(start, abs=0.05)


def test_texel_model_parameters_are_the_srgb_values_that_ship():
    start = torch.tensor([[[0.0, 0.002, 0.2], [0.5, 0.9, 1.0]]])
    model = TexelModel([start, None])
    (encoded,) = model.parameters()
    assert torch.allclose(encoded, linear_to_srgb(start))
    textures, uvs = model.candidate()
    assert uvs is None and textures[1] is None
    assert torch.allclose(textures[0], start, atol=1e-6)
    textures[0].sum().backward()  # d linear / d sRGB is 1 / 12.92 at the dark end
    assert encoded.grad[0, 0, 0] == pytest.approx(1 / 12.92)
    with torch.no_grad():
        encoded += 0.5
    model.project()
    assert encoded.max() == 1.0 and encoded.min() >= 0.5


def test_the_loop_trains_on_the_cameras_it_is_given(scene):
    mesh, renderer, views = scene
    cached = []
    result = optimize(
        renderer,
        lanczos_model(mesh),
        small_config(steps=1),
        on_event=lambda event: cached.append(event.total) if event.phase == "caching" else None,
        validation=fresh_validation(scene),
        setup=LoopSetup(training_cameras=views["Q"].cameras[:3]),
    )
    assert cached == [3, 3, 3] and result.training_views == 3


def test_a_loop_can_take_over_an_earlier_loops_pool_and_validated_start(scene):
    mesh, renderer, views = scene
    validation = fresh_validation(scene)
    pool = training_views(renderer, views["Q"].cameras[:4], validation.sizes, True)
    model = lanczos_model(mesh)
    first = optimize(renderer, model, small_config(steps=2), validation, LoopSetup(pool=pool))
    assert len(pool) == 4 and len(pool.taps) == 4
    model.restore(first.textures)
    validated = []
    counting = validation.psnr
    validation.psnr = lambda *args: validated.append(1) or counting(*args)
    second = optimize(
        renderer, model, small_config(steps=1), validation,
        LoopSetup(pool=pool, start_scores=first.scores),
    )
    assert len(validated) == 1  # its last state only: the start's scores were handed over
    assert second.training_views == 4 and len(pool) == 4  # nothing cached again
    assert validation.rank(second.scores) >= validation.rank(first.scores)


def test_runs_are_deterministic_with_a_seed(scene):
    first, second = run(scene, steps=6), run(scene, steps=6)
    assert torch.equal(first.textures[0], second.textures[0])
    assert first.history == [] or [h["loss"] for h in first.history] == [
        h["loss"] for h in second.history
    ]


def test_step_limit_and_time_budget_stop_the_loop(scene):
    assert run(scene, steps=3).steps == 3
    stopped = run(scene, steps=50, time_budget=0.0)
    assert stopped.steps == 0 and stopped.stopped_by == "time budget"


def test_a_controller_stops_the_loop_from_outside(scene):
    mesh, renderer, _ = scene
    controller = Controller()
    events = []

    def on_event(event):
        events.append(event)
        if event.phase == "step" and event.step == 4:
            controller.stop()

    result = optimize(
        renderer, lanczos_model(mesh), small_config(), fresh_validation(scene),
        on_event=on_event, controller=controller,
    )
    assert result.steps == 4 and result.stopped_by == "stopped"
    phases = [e.phase for e in events]
    assert phases[0] == "caching" and phases[-1] == "done"
    textures, uvs = [e for e in events if e.phase == "step"][-1].candidate()
    assert textures[0].shape == (32, 32, 3) and uvs is None


def test_pause_blocks_until_resumed():
    controller = Controller()
    controller.pause()
    assert controller.paused
    resumed = threading.Event()

    def waiter():
        controller.wait_while_paused()
        resumed.set()

    thread = threading.Thread(target=waiter)
    thread.start()
    assert not resumed.wait(0.05)
    controller.resume()
    assert resumed.wait(2.0)
    thread.join()


def test_direct_method_returns_an_8bit_texture_of_the_target_size():
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    options = MethodOptions(device="cpu", steps=2, settings={"optimize": {"pool_views": 2}})
    renderer = Renderer(mesh, "cpu", Evaluation(views=(0, 1)))
    validation = Validation(validation_view_sets(renderer, 1), output_sizes(mesh, SCALE))
    result = run_method("direct", mesh, SCALE, options, RunContext(renderer, validation))
    (texture,) = result.textures
    assert texture.dtype == np.uint8 and texture.shape == (16, 16, 3)
    assert result.loop.steps == 2 and result.seconds > 0


def test_cached_taps_render_exactly_what_the_renderer_renders(scene):
    _, _, views = scene
    texture = torch.rand(32, 32, 3)
    cached = ViewCache(views["Q"], [(32, 32)], with_taps=True)
    general = ViewCache(views["Q"], [(32, 32)], with_taps=False)
    for view in range(len(cached)):
        torch.testing.assert_close(
            cached.render(view, [texture], None),
            general.render(view, [texture], None),
            atol=2e-6,
            rtol=0,
        )


def test_cached_taps_render_every_material_as_the_renderer_does():
    # two textured materials of different sizes and an untextured one, seen near (texels
    # magnified: one mip level tapped) and far (minified: two)
    mesh = three_material_demo()
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32))
    cameras = [validation_cameras(distance)[view] for distance in (1.5, 6.0) for view in (0, 7)]
    views = ViewSet(renderer, cameras)
    sizes = [(8, 8), (16, 8), None]
    cached = ViewCache(views, sizes, with_taps=True)
    general = ViewCache(views, sizes, with_taps=False)
    generator = torch.Generator().manual_seed(3)
    textures = [torch.rand(*size, 3, generator=generator) for size in sizes[:2]] + [None]
    for view in range(len(views)):
        torch.testing.assert_close(
            cached.render(view, textures, None),
            general.render(view, textures, None),
            atol=2e-6,
            rtol=0,
        )


def test_the_l2_loss_on_the_objects_pixels_is_the_loss_of_the_full_render(scene):
    _, _, views = scene
    cache = ViewCache(views["Q"], [(32, 32)], with_taps=True)
    texture = torch.rand(32, 32, 3)
    for view in range(len(cache)):
        image = cache.render(view, [texture], None)
        full = rendering_loss(image, *views["Q"].reference(view), ssim_weight=0.0)
        torch.testing.assert_close(view_loss(cache, view, [texture], None, 0.0), full)


class _GradientRecorder:
    """An optimiser that keeps the gradient of its one parameter instead of stepping."""

    def __init__(self, parameter: torch.Tensor):
        self.parameter, self.lr, self.gradient = parameter, 0.0, None

    def zero_grad(self) -> None:
        self.parameter.grad = None

    def step(self) -> None:
        self.gradient = self.parameter.grad.clone()


def test_a_step_in_decibels_weighs_each_views_gradient_by_its_own_loss(scene):
    # d/dx mean_v 10 log10(L_v) = mean_v (10 / ln 10) (dL_v / dx) / L_v
    mesh, _, views = scene
    cache = ViewCache(views["Q"], [(32, 32)], with_taps=True)
    model = lanczos_model(mesh)
    (parameter,) = model.parameters()
    chosen = [0, 3]
    expected = torch.zeros_like(parameter)
    for view in chosen:
        parameter.grad = None
        textures, _ = model.candidate()
        loss = view_loss(cache, view, textures, None, 0.0)
        loss.backward()
        expected += 10 / math.log(10) * parameter.grad / loss.item() / len(chosen)
    recorder = _GradientRecorder(parameter)
    config = small_config(loss_in_db=True)
    reported = train_step(cache, model, recorder, chosen, config, lambda: 1.0)
    torch.testing.assert_close(recorder.gradient, expected, rtol=1e-4, atol=1e-6)
    assert reported > 0  # what is reported is the mean loss itself, not its decibels


def test_cached_taps_give_the_renderers_gradient(scene):
    _, _, views = scene
    texture = torch.rand(32, 32, 3)
    cached = ViewCache(views["Q"], [(32, 32)], with_taps=True)
    general = ViewCache(views["Q"], [(32, 32)], with_taps=False)
    weights = torch.rand(views["Q"].renderer.image_size, views["Q"].renderer.image_size, 3)
    gradients = []
    for cache in (cached, general):
        texels = texture.clone().requires_grad_(True)
        (cache.render(0, [texels], None) * weights).sum().backward()
        gradients.append(texels.grad)
    assert gradients[0].abs().max() > 0
    torch.testing.assert_close(gradients[0], gradients[1], atol=1e-5, rtol=1e-4)


def test_dropped_taps_are_found_again_as_a_view_is_next_rendered(scene):
    _, _, views = scene
    cache = ViewCache(views["Q"], [(32, 32)], with_taps=True)
    texture = torch.rand(32, 32, 3)
    before = cache.render(1, [texture], None)  # finds the taps of views 0 and 1
    held = cache.nbytes
    cache.drop_taps()
    assert held > 0 and cache.nbytes == 0 and len(cache.views) == len(views["Q"])
    torch.testing.assert_close(cache.render(1, [texture], None), before, rtol=0, atol=0)
    assert cache.nbytes == held


def test_cached_taps_handle_several_and_untextured_materials():
    mesh = three_material_demo()
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32))
    views = ViewSet(renderer, validation_cameras()[:3])
    textures = [torch.rand(8, 8, 3), torch.rand(16, 8, 3), None]
    sizes = [(8, 8), (16, 8), None]
    cached, general = ViewCache(views, sizes, True), ViewCache(views, sizes, False)
    for view in range(3):
        torch.testing.assert_close(
            cached.render(view, textures, None),
            general.render(view, textures, None),
            atol=2e-6,
            rtol=0,
        )


def uncached_validation(scene) -> Validation:
    """A validation like :func:`fresh_validation` whose views are not cached yet."""
    mesh, renderer, views = scene
    fresh = {name: ViewSet(renderer, v.cameras, eager=False) for name, v in views.items()}
    return Validation(fresh, output_sizes(mesh, SCALE))


def test_views_are_cached_between_steps_by_count_not_by_time(scene):
    # 4 training views before the first step, then 2 views after each step: validation views
    # until they are as many as the training views, then the two in turn.
    three = run(scene, uncached_validation(scene), steps=3)
    assert three.training_views == 5  # steps 1-2: 4 validation views; step 3: one of each
    six = run(scene, uncached_validation(scene), steps=6)
    assert six.training_views == 8  # the validation views left are cached at the end:
    assert six.validation_views == {"Q": 6, "near": 2, "far": 2}


def test_views_stop_being_cached_once_they_hold_the_view_memory(scene):
    # A limit that the first views already exceed: the first step's 4 training views, then
    # no more; the validation freezes at the least it validates on.
    full = run(scene, uncached_validation(scene), steps=6, view_memory=1)
    assert full.steps == 6 and full.training_views == 4
    assert full.validation_views == {"Q": 3, "near": 2, "far": 2}
    # Room for every view: the same as without a limit.
    roomy = run(scene, uncached_validation(scene), steps=6, view_memory=1 << 40)
    assert roomy.training_views == 8
    assert roomy.validation_views == {"Q": 6, "near": 2, "far": 2}


def test_views_stop_being_cached_once_the_process_holds_the_memory_limit(scene, monkeypatch):
    monkeypatch.setattr(loop_module, "resident_bytes", lambda: 2_000_000_000)
    # A limit the process already holds: as a full view memory, the first step's views only.
    full = run(scene, uncached_validation(scene), steps=6, memory_limit=2_000_000_000)
    assert full.steps == 6 and full.training_views == 4
    assert full.validation_views == {"Q": 3, "near": 2, "far": 2}
    # A byte more of room is not room for a view of the mean size: the same.
    byte = run(scene, uncached_validation(scene), steps=6, memory_limit=2_000_000_001)
    assert byte.training_views == 4
    # Room for every view: as without a limit.
    roomy = run(scene, uncached_validation(scene), steps=6, memory_limit=3_000_000_000)
    assert roomy.training_views == 8
    assert roomy.validation_views == {"Q": 6, "near": 2, "far": 2}
    # Where the system cannot say what the process holds, no limit applies.
    monkeypatch.setattr(loop_module, "resident_bytes", lambda: None)
    unknown = run(scene, uncached_validation(scene), steps=6, memory_limit=1)
    assert unknown.training_views == 8


def test_the_pool_grows_again_once_the_process_falls_below_the_memory_limit(
    scene, monkeypatch
):
    """A loop that starts at the limit (a race's continuation, its first step's buffers and the
    trials' leftovers held) freezes its validation at the least, but its training pool grows
    once a later step leaves room: it no longer trains on its first 4 views for the rest."""
    readings = iter([2_000_000_000] * 6)
    monkeypatch.setattr(loop_module, "resident_bytes", lambda: next(readings, 1_000_000_000))
    run_ = run(scene, uncached_validation(scene), steps=6, memory_limit=1_500_000_000)
    assert run_.validation_views == {"Q": 3, "near": 2, "far": 2}  # frozen at the limit
    assert run_.training_views > 4  # 2 more a step once there was room (4: it stayed shut)


def test_a_method_limits_its_loops_to_more_memory_than_the_process_holds_as_it_starts(
    monkeypatch,
):
    monkeypatch.setattr("geoscaler.methods.learned.resident_bytes", lambda: 700_000_000)
    defaults = {"steps": 10}
    config = loop_config(defaults, MethodOptions(), RunContext())
    assert config.memory_limit == 700_000_000 + METHOD_MEMORY
    given = MethodOptions(settings={"optimize": {"memory_limit": None}})
    assert loop_config(defaults, given, RunContext()).memory_limit is None
    monkeypatch.setattr("geoscaler.methods.learned.resident_bytes", lambda: None)
    assert loop_config(defaults, MethodOptions(), RunContext()).memory_limit is None


def test_cached_views_count_the_bytes_of_every_tensor_they_hold(scene):
    _, renderer, views = scene
    q = ViewSet(renderer, views["Q"].cameras[:2])
    image = 64 * 64 * (3 * 4 + 1)  # a float32 sRGB reference and a bool mask
    assert q.nbytes == 2 * image + sum(g.nbytes for g in q.gbuffers)
    assert q.references.shape == (2, 64, 64, 3)  # stacked: a copy, not kept
    assert q.nbytes == 2 * image + sum(g.nbytes for g in q.gbuffers)
    cache = ViewCache(q, [(32, 32)], with_taps=True)
    assert cache.nbytes == 0  # no taps found yet
    cache.find_taps(0)
    pixels = len(cache.object_pixels[0])
    assert cache.nbytes == cache.taps[0][0].nbytes + pixels * (8 + 3 * 4 + 3 * 4)


def test_a_loop_whose_baseline_is_already_invisible_stops_once_each_set_has_its_least_views(
    scene,
):
    # The original itself as the baseline (full size): it renders as the reference does, on
    # every view. Views are cached as in the test above: after step 5 Q has 3 views and the
    # guards their 2 (all they have), and the loop stops there.
    mesh, renderer, views = scene
    original = reference_textures(mesh)[0]

    def run_from_the_original(**overrides):
        fresh = {name: ViewSet(renderer, v.cameras, eager=False) for name, v in views.items()}
        validation = Validation(fresh, [original.shape[:2]], {"original": [original]})
        model = TexelModel([texture_to_linear(original)])
        return optimize(renderer, model, small_config(**overrides), validation)

    stopped = run_from_the_original(finish_when_invisible=True)
    assert stopped.stopped_by == NOTHING_TO_GAIN and stopped.steps == 5
    assert run_from_the_original().steps == 30  # a loop that is not asked to stop: all its steps


def test_a_loop_whose_baseline_is_visibly_off_makes_its_steps(scene):
    mesh, _, _ = scene
    validation = uncached_validation(scene)
    validation.baselines = {"lanczos": [lanczos(reference_textures(mesh)[0], SCALE)]}
    result = run(scene, validation, finish_when_invisible=True)
    assert result.stopped_by == "steps" and result.steps == 30
    assert max(validation.worst_baseline_views().values()) < 50.0


def test_a_frozen_validation_reads_the_worst_baseline_view_from_the_floors_scores(scene):
    mesh, _, _ = scene
    baseline = lanczos(reference_textures(mesh)[0], SCALE)
    validation = fresh_validation(scene, {"lanczos": [baseline]})
    before_freezing = validation.worst_baseline_views()  # rendered anew, view by view
    validation.freeze()
    floor = validation.baseline_scores()["lanczos"]
    lowest = min(float(np.nanmin(values)) for values in floor.per_view.values())
    for cache in validation.sets.values():
        cache.score = None  # rendering the baseline again would call it
    assert validation.worst_baseline_views() == {"lanczos": lowest}
    assert before_freezing["lanczos"] == pytest.approx(lowest, abs=1e-4)


def test_a_spent_budget_validates_on_what_is_cached_and_ships_the_start(scene):
    mesh, renderer, _ = scene
    validation = uncached_validation(scene)
    result = optimize(
        renderer,
        lanczos_model(mesh),
        small_config(time_budget=1.0),
        validation,
        budget=Budget(ManualClock(), -1e9, 1.0),  # the budget ran out long ago
    )
    assert result.steps == 0 and result.stopped_by == "time budget" and result.best_step == 0
    assert result.training_views == 0  # no view cached for a step that cannot be taken
    assert result.validation_views == {"Q": 3, "near": 2, "far": 2}  # the least it validates on


class _Floor:
    """A stand-in validation whose floor is 30 dB far away (and nothing elsewhere)."""

    def rank(self, scores):
        return min(0.0, scores["far"] - 30.0), scores["Q"]


def test_the_best_candidate_clears_the_floor_before_it_scores_on_q():
    best = _Best(_Floor())
    candidate = ([torch.zeros(2, 2, 3)], None)
    assert best.offer({"Q": 31.0, "far": 30.5}, candidate, 0)  # the start clears
    assert not best.offer({"Q": 35.0, "far": 29.0}, candidate, 10)  # sharper, worse far away
    assert best.offer({"Q": 32.0, "far": 30.2}, candidate, 20)
    assert (best.step, best.psnr, best.clears) == (20, 32.0, True)


def test_without_a_candidate_that_clears_the_one_that_falls_least_below_is_kept():
    best = _Best(_Floor())
    candidate = ([torch.zeros(2, 2, 3)], None)
    assert best.offer({"Q": 31.0, "far": 20.0}, candidate, 0)
    assert best.offer({"Q": 30.0, "far": 21.0}, candidate, 10)
    assert not best.offer({"Q": 33.0, "far": 20.5}, candidate, 20)
    assert (best.step, best.clears) == (10, False)


class _Costing(Validation):
    """A validation whose remaining work (validations owed, scorings after) takes ``seconds``."""

    def __init__(self, views, sizes, seconds: float, clock: Clock = WALL_CLOCK):
        super().__init__(views, sizes, clock=clock)
        self.seconds = seconds

    def seconds_needed(self, validations, caching, view_seconds=0.0):
        return self.seconds


def test_the_loop_stops_when_what_must_follow_it_would_overrun_the_budget(scene):
    mesh, renderer, views = scene
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=1000.0)
    result = optimize(renderer, lanczos_model(mesh), small_config(time_budget=600.0), validation)
    assert result.steps == 0 and result.stopped_by == "time budget" and result.best_step == 0


class _CostingViews(Validation):
    """A validation whose remaining work is ``count`` views at the price it is given."""

    def __init__(self, views, sizes, count: int, clock: Clock = WALL_CLOCK):
        super().__init__(views, sizes, clock=clock)
        self.count = count

    def seconds_needed(self, validations, caching, view_seconds=0.0):
        return self.count * view_seconds


def slow_caching(
    scene, monkeypatch, seconds: float | list[float], clock: ManualClock
) -> Renderer:
    """The scene's renderer, on whose ``clock`` caching each view takes ``seconds`` (or the
    n-th view ``seconds[n]``); nothing else takes any time on it."""
    mesh, renderer, _ = scene
    slow = Renderer(mesh, "cpu", renderer.evaluation)
    cached_view = slow.cached_view
    delays = iter(seconds) if isinstance(seconds, list) else None

    def slow_view(camera):
        clock.advance(seconds if delays is None else next(delays, 0.0))
        return cached_view(camera)

    monkeypatch.setattr(slow, "cached_view", slow_view)
    return slow


def slow_steps(monkeypatch, seconds: float, clock: ManualClock) -> None:
    """Every training step takes ``seconds`` on ``clock`` (plain and majorized alike)."""
    for name in ("train_step", "majorized_step"):
        step = getattr(loop_module, name)

        def slow_step(*args, step=step, **kwargs):
            clock.advance(seconds)
            return step(*args, **kwargs)

        monkeypatch.setattr(loop_module, name, slow_step)


def slow_run(
    scene, monkeypatch, clock: ManualClock, view_seconds: float, step_seconds: float
) -> Renderer:
    """The scene's renderer on ``clock``: caching a view takes ``view_seconds``, a step
    ``step_seconds`` (:func:`slow_caching`, :func:`slow_steps`)."""
    slow_steps(monkeypatch, step_seconds, clock)
    return slow_caching(scene, monkeypatch, view_seconds, clock)


def run_on(clock: ManualClock, renderer, validation, time_budget: float):
    """The loop of the scene's Lanczos start under ``time_budget`` seconds of ``clock``."""
    model, config = lanczos_model(renderer.mesh), small_config(time_budget=time_budget)
    budget = Budget(clock, clock.now(), time_budget)
    return optimize(renderer, model, config, validation, budget=budget)


def test_the_loop_keeps_a_margin_on_what_must_follow_it(scene):
    # 15 s must follow the loop in a 20 s budget: it would fit, not with its margin (22.5 s)
    mesh, renderer, views = scene
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=15.0)
    result = optimize(renderer, lanczos_model(mesh), small_config(time_budget=20.0), validation)
    assert FINISH_MARGIN * 15.0 > 20.0
    assert result.steps == 0 and result.stopped_by == "time budget"


def test_under_a_budget_the_first_step_waits_for_one_training_view(scene, monkeypatch):
    # caching a view takes 0.25 s: the first step comes after one view, not views_per_step (4,
    # 1 s: past the 0.8 s budget); the pool grows between the steps that follow
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_caching(scene, monkeypatch, 0.25, clock)
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=0.0, clock=clock)  # none
    result = run_on(clock, slow, validation, time_budget=0.8)
    assert small_config().views_per_step == 4
    assert result.first_step_seconds == 0.25 and result.history[0]["elapsed"] == 0.25
    assert result.steps >= 2 and result.training_views >= 2


def test_a_first_step_that_cannot_fit_in_the_budget_is_not_started(scene, monkeypatch):
    # one view (0.25 s) is cached; then the validation the loop owes (0.5 s, 0.75 s with its
    # margin) no longer fits in the 0.55 s left of a 0.8 s budget
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_caching(scene, monkeypatch, 0.25, clock)
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=0.5, clock=clock)
    result = run_on(clock, slow, validation, time_budget=0.8)
    assert FINISH_MARGIN * 0.5 > 0.8 - 0.25
    assert result.training_views == 1
    assert result.steps == 0 and result.stopped_by == "time budget" and result.best_step == 0


def test_one_slow_view_does_not_price_every_view_still_to_cache(scene, monkeypatch):
    # Steps of 0.03 s; 3 views at 0.05 s and one at 0.6 s, cached by the end of step 4; 7
    # views still to cache after the loop. Priced at the costliest (7 * 0.6 * FINISH_MARGIN =
    # 6.3 s) they would overrun the 3.2 s left of a 4 s budget and stop the loop there; at the
    # mean (at most 0.19 s a view: 2 s) they fit, and every step is taken.
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_caching(scene, monkeypatch, [0.05, 0.05, 0.05, 0.6], clock)
    slow_steps(monkeypatch, 0.03, clock)
    validation = _CostingViews(views, output_sizes(mesh, SCALE), count=7, clock=clock)
    result = run_on(clock, slow, validation, time_budget=4.0)
    assert result.training_views >= 4 and result.steps == small_config().steps


def test_under_a_budget_caching_between_steps_takes_no_more_time_than_the_steps(
    scene, monkeypatch
):
    # A view takes 0.25 s, a step 0.0625 s, the validation views are cached already. The
    # pool's first 4 views (views_per_step) are owed: one before step 1, two after it. Beyond
    # them, after step k a view is cached where the 0.25 s of each of the n cached so far fit
    # in k steps' time (0.25 n <= 0.0625 k): after steps 1, 4, 8, ..., 28, one view each.
    # Without the balance, two views after every step: the 16 of the pool by step 8.
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_run(scene, monkeypatch, clock, view_seconds=0.25, step_seconds=0.0625)
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=0.0, clock=clock)
    result = run_on(clock, slow, validation, time_budget=20.0)  # a window of 8 s: never shut
    assert CACHING_PER_STEPPING == 1.0
    assert result.steps == 30 and result.training_views == 1 + 2 + 8


def views_cached_by_step(scene, monkeypatch, steps: int, **overrides):
    """The loop of the scene's Lanczos start under a 20 s budget of a clock on which caching a
    view takes 0.25 s and a step 0.0625 s, no validation view cached before: its result, and
    step -> the views (training and validation) cached as that step ended."""
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_run(scene, monkeypatch, clock, view_seconds=0.25, step_seconds=0.0625)
    uncached = {name: ViewSet(slow, v.cameras, eager=False) for name, v in views.items()}
    validation = Validation(uncached, output_sizes(mesh, SCALE), clock=clock)
    cached_at_step = {}

    def on_event(event):
        if event.phase == "step":
            cached_at_step[event.step] = event.done

    config = small_config(time_budget=20.0, steps=steps, **overrides)
    model, budget = lanczos_model(mesh), Budget(clock, 0.0, 20.0)
    result = optimize(slow, model, config, validation, budget=budget, on_event=on_event)
    return result, cached_at_step


def test_under_a_budget_the_views_owed_in_any_case_are_not_held_back(
    scene, monkeypatch
):
    # The views owed in any case, the pool's first 4 and the validation's least (Q 3, near 2,
    # far 2), come 2 after each step whatever the steps took, and after step 1 one more that
    # the balance allows (no caching yet, 0.0625 s of steps): 1, 4, 6, 8 views cached as
    # steps 1-4 end. Held back like the rest: 1, 2, 2, 2 (one view after step 1, the next
    # once the steps have taken its 0.25 s, after step 4).
    _, cached_at_step = views_cached_by_step(scene, monkeypatch, steps=6)
    assert [cached_at_step[step] for step in (1, 2, 3, 4)] == [1, 4, 6, 8]


def test_under_a_budget_the_views_owed_in_any_case_are_cached_at_the_memory_limit(
    scene, monkeypatch
):
    # The process holds its memory limit from the start (a race's later trial, the trials
    # before it holding their views): the views owed in any case still come, and no view
    # beyond them. After step 1, two owed views, then the validation freezes at the limit,
    # caching its least (Q 3, near 2, far 2) first: 9 views as step 2 ends; after step 2 the
    # pool's last owed view (4, views_per_step): 11. A pool of one view for the whole loop
    # trained it to that view alone.
    monkeypatch.setattr(loop_module, "resident_bytes", lambda: 2_000_000_000)
    result, cached_at_step = views_cached_by_step(
        scene, monkeypatch, steps=8, memory_limit=1_000_000_000
    )
    assert [cached_at_step[step] for step in range(1, 9)] == [1, 9, 11, 11, 11, 11, 11, 11]
    assert result.training_views == 4
    assert result.validation_views == {"Q": 3, "near": 2, "far": 2}


def test_a_race_s_first_trial_leaves_room_for_one_more_pool_as_it_caches_the_validation(
    monkeypatch,
):
    # Once the pool stops growing, validation views are cached up to the memory limit: each
    # takes 10 bytes here, from 500, against a limit of 1000. Leaving room for the taps of
    # a later layout's pool as large as this one's (200 bytes), 30 of them instead of 50.
    from geoscaler.optim.loop import OptimizeConfig, _Caching

    class Pool:
        nbytes = 0  # its views' own bytes, shared by every layout's pool

        def __init__(self):
            self.cameras = [None] * 1000

        def __len__(self):
            return 1000

    class Train:
        nbytes = 200  # the taps

        def __init__(self):
            self.views = Pool()

    class FewViews:  # a validation that caches one more view a call
        sets, frozen, num_views = {}, False, 0

        def cache_next(self):
            self.num_views += 1
            return True

        def freeze(self):
            self.frozen = True

    def validation_cached(room: bool) -> int:
        validation = FewViews()
        resident = lambda: 500 + 10 * validation.num_views  # noqa: E731
        monkeypatch.setattr(loop_module, "resident_bytes", resident)
        config = OptimizeConfig(memory_limit=1000, view_memory=None)
        budget = Budget(ManualClock(), 0.0, None)
        emit = lambda *args, **fields: None  # noqa: E731
        caching = _Caching(Train(), validation, config, budget, emit, room_for_a_pool=room)
        caching.close()
        assert validation.frozen
        return validation.num_views

    assert validation_cached(False) == 50
    assert validation_cached(True) == 30


def test_a_finished_loop_leaves_its_training_pool_to_reference_counting(scene):
    # Nothing of a finished loop refers back to itself: the pool it trained on is freed as
    # its last holder lets go, not at the garbage collector's next pass (a race's losing
    # layout kept the memory its winner's pool was to grow into).
    mesh, renderer, views = scene
    validation = fresh_validation(scene)
    pool = training_views(renderer, views["Q"].cameras[:4], validation.sizes, True)
    setup = LoopSetup(pool=pool)
    gc.disable()
    try:
        optimize(renderer, lanczos_model(mesh), small_config(steps=2), validation, setup)
        freed = weakref.ref(pool)
        del pool, setup
        assert freed() is None
    finally:
        gc.enable()


def test_no_view_is_cached_after_a_step_past_the_loops_budget(scene, monkeypatch):
    # A view takes 0.25 s, a step 0.0625 s, nothing need follow the loop. Step 1 ends at
    # 0.3125 s of a 0.5 s budget: the pool's owed views (two after it, 0.5 s) would end at
    # 0.8125 s, so none is cached; steps on the one view go on to the budget's end (4: at
    # 0.3125, 0.375, 0.4375 and 0.5 s).
    mesh, _, views = scene
    clock = ManualClock()
    slow = slow_run(scene, monkeypatch, clock, view_seconds=0.25, step_seconds=0.0625)
    validation = _Costing(views, output_sizes(mesh, SCALE), seconds=0.0, clock=clock)
    result = run_on(clock, slow, validation, time_budget=0.5)
    assert result.training_views == 1 and result.steps == 4
    assert clock.now() <= 0.5


def test_restoring_texels_gives_back_the_candidate_they_came_from(scene):
    mesh, _, _ = scene
    model = lanczos_model(mesh)
    (saved,), _ = model.candidate()
    saved = saved.detach().clone()
    with torch.no_grad():
        model.parameters()[0].mul_(0.5)
    model.restore([saved])
    torch.testing.assert_close(model.candidate()[0][0], saved, atol=1e-6, rtol=0)


def test_a_candidate_that_validates_worse_sends_the_loop_back_to_its_best_at_a_lower_rate(scene):
    # A rate of 50 ruins the texture in a step: each validation after the start's ranks below
    # it, sends the texels back to the start and quarters the rate, until the rate helps. The
    # first comes as the sets freeze (after step 1), each next one 10 * 0.25 = 2 steps later.
    result = run(scene, steps=8, lr=50.0, warmup_steps=1, backtrack=0.25)
    backtracked = [(h["step"], h["backtrack"]) for h in result.history if "backtrack" in h]
    assert backtracked == [(1, 0.25), (3, 0.0625), (5, 0.015625), (7, 0.00390625)]
    assert result.backtracks == 4 and result.best_step == 8
    start = run(scene, steps=0)  # the start, finished and validated alone
    assert result.best_psnr > start.best_psnr
    without = run(scene, steps=8, lr=50.0, warmup_steps=1)
    assert without.best_step == 0  # the ruined texture never beat the start


def test_without_backtracking_no_candidate_is_validated_as_the_sets_freeze(scene):
    result = run(scene, steps=8, lr=50.0, warmup_steps=1)
    validated = [h["step"] for h in result.history if "validation_psnr_fg" in h]
    assert validated == [8] and result.backtracks == 0


def test_closing_the_caching_caches_no_view_past_the_loops_own_end():
    """A loop whose budget ends before the caching window (a race's first trial) stops
    caching validation views at its end; one within its budget caches to the window's end."""
    from types import SimpleNamespace

    class Pool:  # a training pool of no view
        cameras: list = []
        nbytes = 0

        def __len__(self) -> int:
            return 0

    def closed(loop_end: float, share: float = loop_module.CACHING_SHARE) -> list[float]:
        """When each validation view was cached (one second each) as a loop ending at
        ``loop_end`` seconds of a 20 s budget, caching within ``share`` of it, closes its
        caching."""
        clock, cached = ManualClock(), []

        def cache_next() -> bool:
            clock.advance(1.0)
            cached.append(clock.now())
            return True

        validation = SimpleNamespace(cache_next=cache_next, freeze=lambda: None, sets={},
                                     num_views=0)  # fmt: skip
        train = SimpleNamespace(views=Pool(), nbytes=0)
        config = OptimizeConfig(time_budget=20.0, view_memory=None)
        budget = Budget(clock, 0.0, 20.0, 20.0 - loop_end)
        quiet = lambda *args, **fields: None  # noqa: E731
        loop_module._Caching(train, validation, config, budget, quiet, share).close()
        return cached

    window = loop_module.CACHING_SHARE * 20.0  # from the budget's start: 8 s
    assert closed(20.0) == [float(s) for s in range(1, int(window) + 1)]
    assert closed(3.0) == [1.0, 2.0, 3.0]  # the last begun before the loop's end
    assert closed(20.0, share=0.24) == [1.0, 2.0, 3.0, 4.0, 5.0]  # a window of 4.8 s
