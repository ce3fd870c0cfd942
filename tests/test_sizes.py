"""The sizes users ask for: what --scale, --max-size and --power-of-two promise, per class."""

import pytest

from geoscaler.errors import GeoscalerError
from geoscaler.pipeline.arguments import check_image_format, check_size_plan
from geoscaler.resize.filters import target_size
from geoscaler.resize.sizes import SizeRule, nearest_power_of_two, size_plan


@pytest.mark.parametrize(
    ("rule", "size", "expected"),
    [
        (SizeRule(scale=4), (1000, 750), (250, 188)),  # 187.5 rounds half up
        (SizeRule(scale=8), (1000, 750), (125, 94)),
        (SizeRule(scale=4), (4096, 512), (1024, 128)),
        (SizeRule(max_size=512), (1000, 750), (512, 384)),
        (SizeRule(max_size=1000), (4096, 512), (1000, 125)),
        (SizeRule(max_size=2048), (1000, 750), (1000, 750)),  # never enlarged
        (SizeRule(power_of_two=True), (1000, 750), (512, 512)),  # 1024 > 1000: not enlarged
        (SizeRule(power_of_two=True), (4096, 512), (4096, 512)),
        (SizeRule(scale=4, power_of_two=True), (1000, 750), (256, 128)),  # 188 is nearer 128
        (SizeRule(max_size=1000, power_of_two=True), (4096, 512), (512, 128)),  # 1024 > 1000
        (SizeRule(scale=4, max_size=200), (1000, 750), (200, 150)),
        (SizeRule(scale=2, max_size=300, power_of_two=True), (1000, 750), (256, 256)),
    ],
)
def test_a_rule_gives_the_size_it_promises(rule, size, expected):
    assert rule.size(*size) == expected


@pytest.mark.parametrize("size", [(1000, 750), (4096, 512), (3, 5), (1, 1)])
@pytest.mark.parametrize("limit", [1, 7, 100, 1024])
def test_max_size_bounds_the_longer_side_and_keeps_the_aspect(size, limit):
    h, w = SizeRule(max_size=limit, power_of_two=True).size(*size)
    assert max(h, w) <= limit and h <= size[0] and w <= size[1]
    assert h & (h - 1) == 0 and w & (w - 1) == 0
    h, w = SizeRule(max_size=limit).size(*size)
    longer = min(limit, max(size))
    assert max(h, w) == longer
    exact_shorter = min(size) * longer / max(size)  # the aspect kept, to the nearest texel
    assert min(h, w) == max(int(exact_shorter + 0.5), 1)


def test_nearest_power_of_two_rounds_ties_up():
    assert [nearest_power_of_two(n) for n in (1, 2, 3, 5, 6, 7, 750, 768, 1000)] == [
        1, 2, 4, 4, 8, 8, 512, 1024, 1024,
    ]  # fmt: skip


def test_a_scale_rule_is_the_protocols_target_size():
    for size in [(1000, 750), (2048, 2048), (17, 9)]:
        assert SizeRule(scale=2).size(*size) == target_size(*size, 2)


def test_bad_rules_are_refused_with_the_flag_named():
    with pytest.raises(GeoscalerError, match="--scale 1"):
        SizeRule(scale=1)
    with pytest.raises(GeoscalerError, match="--max-size 0"):
        SizeRule(max_size=0)
    with pytest.raises(GeoscalerError, match="larger than the 4 x 4 texture"):
        SizeRule(scale=8).size(4, 4)


def test_per_class_values_override_the_value_for_every_class():
    plan = check_size_plan(["4", "normal=2"], ["data=256"], power_of_two=True)
    assert plan.color == SizeRule(scale=4, power_of_two=True)
    assert plan.normal == SizeRule(scale=2, power_of_two=True)
    assert plan.data == SizeRule(scale=4, max_size=256, power_of_two=True)
    assert plan.rule("normal") is plan.normal


def test_scale_four_is_the_default_only_when_no_size_is_asked():
    assert check_size_plan(None, None).color == SizeRule(scale=4)
    assert check_size_plan(None, ["1024"]).color == SizeRule(max_size=1024)


@pytest.mark.parametrize(
    ("scales", "message"),
    [
        (["shiny=2"], "--scale: 'shiny=2': texture class 'shiny' unknown"),
        (["four"], "--scale: 'four' is not a whole number"),
        (["normal=1"], "--scale 1"),
    ],
)
def test_bad_size_flags_say_what_to_write(scales, message):
    with pytest.raises(GeoscalerError, match=message):
        check_size_plan(scales, None)


def test_size_plan_refuses_an_unknown_class():
    with pytest.raises(GeoscalerError, match="texture class 'albedo'"):
        size_plan({"albedo": 2}, {})


def test_image_formats():
    assert [check_image_format(n) for n in (None, "PNG", "jpg", "webp")] == [
        None, "png", "jpeg", "webp",
    ]  # fmt: skip
    with pytest.raises(GeoscalerError, match="--image-format 'gif'"):
        check_image_format("gif")


def test_labels_name_the_rule():
    assert SizeRule(scale=4).label == 4
    assert SizeRule(scale=4, max_size=1024).label == "x4, <= 1024"
    assert SizeRule(power_of_two=True).label == "power of two"
