"""The classifier's settings are declared once; range checks and node parameters come from there."""

from __future__ import annotations

import dataclasses

import pytest

from eit_skin.ros.parameters import CLASSIFIER, NODE_PARAMETERS
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import SegmentationConfig
from eit_skin.touch.settings import Setting, declared_settings, setting, settings_from

SETTINGS = declared_settings(ClassifierConfig)


def test_every_field_is_a_declared_setting_with_a_meaning() -> None:
    names = [s.name for s in SETTINGS]
    fields = [f.name for f in dataclasses.fields(ClassifierConfig) if f.name != "segmentation"]
    seg = [f.name for f in dataclasses.fields(SegmentationConfig)]
    assert names == seg + fields  # nested settings in the place of their field
    defaults = ClassifierConfig()
    for s in SETTINGS:
        owner = defaults.segmentation if s.name in seg else defaults
        assert getattr(owner, s.name) == s.default, s.name
        assert s.kind in (int, float) and len(s.description) > 20, s.name


def _outside(s: Setting) -> list:
    """Values just outside each bound of ``s`` (of its type)."""
    step = 1 if s.kind is int else 1e-9
    bad = []
    if s.low is not None:
        bad.append(s.kind(s.low) if s.low_open else s.kind(s.low - step))
    if s.high is not None:
        bad.append(s.kind(s.high) if s.high_open else s.kind(s.high + step))
    return bad


@pytest.mark.parametrize("setting", SETTINGS, ids=lambda s: s.name)
def test_every_bound_is_checked_naming_the_setting(setting: Setting) -> None:
    seg = {f.name for f in dataclasses.fields(SegmentationConfig)}

    def build(value):
        if setting.name in seg:
            return ClassifierConfig(segmentation=SegmentationConfig(**{setting.name: value}))
        return ClassifierConfig(**{setting.name: value})

    assert setting.low is not None or setting.high is not None  # every setting is bounded
    for value in [*_outside(setting), float("nan")]:
        with pytest.raises(ValueError, match=f"^{setting.name} must be"):
            build(value)
    for bound, is_open in ((setting.low, setting.low_open), (setting.high, setting.high_open)):
        if bound is not None and not is_open and setting.name != "k_low":  # k_low <= k_high
            build(setting.kind(bound))  # a closed bound is allowed


def test_range_texts_read_like_intervals() -> None:
    by_name = {s.name: s for s in SETTINGS}
    assert by_name["pinch_closing"].bounds_text() == "(0, 1)"
    assert by_name["strong_fraction"].bounds_text() == "[0, 1)"
    assert by_name["learn_fraction"].bounds_text() == "(0, 1]"
    assert by_name["start_frames"].bounds_text() == ">= 1"
    assert by_name["k_detect"].bounds_text() == "> 0"
    assert by_name["end_hold_s"].parameter_text() == "time without contact before END; s; >= 0"
    with pytest.raises(ValueError, match=r"pinch_closing must be in \(0, 1\), got 1.5"):
        ClassifierConfig(pinch_closing=1.5)
    assert setting(1.0, "s", "<= 2.5e-3", "a time").metadata  # one-sided upper, exponent
    with pytest.raises(ValueError, match=r"bounds '0\.\.1'"):
        setting(0.5, "", "0..1", "a fraction written the wrong way")


def test_the_node_offers_every_setting_it_can_honour_as_declared() -> None:
    table = {name: (default, text) for name, default, text in CLASSIFIER}
    for s in SETTINGS:
        if s.node:
            assert table[s.name] == (s.default, s.parameter_text()), s.name
            assert type(table[s.name][0]) is s.kind
        else:
            assert s.name not in table, s.name
    # no other node has a parameter of the same name (one launch argument would set both)
    others = {n for exe, t in NODE_PARAMETERS.items() if exe != "eit_classifier" for n, _, _ in t}
    assert not others & {s.name for s in SETTINGS}


def test_a_config_from_parameter_values_takes_every_value() -> None:
    values = {name: default for name, default, _ in CLASSIFIER}
    assert settings_from(ClassifierConfig, values) == ClassifierConfig()
    values.update(k_high=8, start_frames=3.0, rub_travel=1.5, min_pixels=4)
    config = settings_from(ClassifierConfig, values)
    assert config.segmentation.k_high == 8.0 and type(config.segmentation.k_high) is float
    assert config.start_frames == 3 and type(config.start_frames) is int
    assert config.rub_travel == 1.5 and config.segmentation.min_pixels == 4
    with pytest.raises(ValueError, match=r"grab_spread must be > 0, got -1\.0"):
        settings_from(ClassifierConfig, {"grab_spread": -1})
