"""The settings builder every front end calls: names, solver settings, one-line errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream
from pearl_ros.online import segmenter as module
from pearl_ros.online.config import (
    OnlineConfig,
    build_configs,
    known_names,
    parse_assignments,
    setting_values,
    solver_names,
    unknown_parameter,
    user_names,
)
from pearl_ros.online.segmenter import OnlineSegmenter


def configs(*items: str) -> tuple[PearlConfig, OnlineConfig]:
    """What a front end builds from ``--set`` items."""
    return build_configs(parse_assignments(items))


def test_user_names_leave_the_solver_out_and_known_names_hold_both():
    assert 'label_cost' in user_names() and 'window' in user_names()
    assert not any(name.startswith('solver') for name in user_names())
    assert 'solver.max_passes' in solver_names()
    assert len(solver_names()) == len(dataclasses.fields(SolverSettings))
    assert known_names() == user_names() + solver_names()


@pytest.mark.parametrize('name, suggestion', [
    ('label_cots', 'label_cost'),
    ('solver.pach_size', 'solver.patch_size'),
    ('patch_size', 'solver.patch_size'),  # a solver setting without its prefix
    ('solver.label_cost', 'label_cost'),  # a user parameter given as a solver setting
    ('windw', 'window'),
])
def test_an_unknown_name_is_refused_in_one_line_with_the_closest_known_name(name, suggestion):
    for build in (lambda: parse_assignments([f'{name}=1']), lambda: build_configs({name: 1})):
        with pytest.raises(InputError) as info:
            build()
        message = str(info.value)
        assert message == f'unknown parameter {name!r} (did you mean {suggestion!r}?)'


def test_a_name_like_no_other_gets_no_suggestion_and_no_list_of_names():
    message = str(unknown_parameter('xyzzy'))
    assert message == "unknown parameter 'xyzzy'"
    # A front end's own names join the candidates.
    assert str(unknown_parameter('layot', known_names() + ('layout',))).endswith(
        "(did you mean 'layout'?)")


def test_a_solver_setting_set_by_name_builds_the_settings_with_it_and_keeps_the_rest():
    config, online = configs('solver.patch_size=10', 'solver.proposal_levels=1,3',
                             'solver.stranger=6', 'label_cost=300')
    assert config.solver == SolverSettings(patch_size=10, proposal_levels=(1.0, 3.0),
                                           stranger=6.0)
    assert config == PearlConfig(label_cost=300.0, solver=config.solver)
    assert online == OnlineConfig()
    # Over a base, the base's other settings stay.
    base = (PearlConfig(solver=SolverSettings(max_passes=2)), OnlineConfig(window=5))
    config, online = build_configs({'solver.split_tries': 0}, base)
    assert config.solver == SolverSettings(max_passes=2, split_tries=0)
    assert online.window == 5


def test_the_values_of_a_pair_of_configs_build_the_same_pair_again():
    pair = configs('solver.patch_size=10', 'solver.proposal_levels=1,3', 'label_cost=300',
                   'window=6')
    values = setting_values(*pair)
    assert tuple(values) == known_names()
    assert values['solver.patch_size'] == 10 and values['window'] == 6
    assert build_configs(values) == pair


def test_ints_and_lists_from_a_file_are_the_floats_and_tuples_of_the_settings():
    config, _ = build_configs({'solver.stranger': 6, 'solver.proposal_levels': [1, 2],
                               'label_cost': 300})
    assert type(config.solver.stranger) is float and config.solver.stranger == 6.0
    assert config.solver.proposal_levels == (1.0, 2.0)
    assert all(type(level) is float for level in config.solver.proposal_levels)
    assert type(config.label_cost) is float


@pytest.mark.parametrize('items, message', [
    (['solver.patch_size=1'], r'^solver\.patch_size must be >= 2, got 1$'),
    (['solver.max_passes=2.5'], r"^invalid value for solver\.max_passes: '2\.5' is not int$"),
    (['solver.proposal_levels=1;2'], 'is not comma-separated numbers'),
    (['solver.proposal_levels=0.2,1'], r'^solver\.proposal_levels must be >= sigma_floor'),
    (['solver.split_share_min=0.5', 'solver.split_share_max=0.4'],
     r'^solver\.split_share_min must be <= split_share_max'),
])
def test_a_bad_solver_value_is_refused_naming_it(items, message):
    with pytest.raises(InputError, match=message):
        configs(*items)


def test_a_label_cost_weight_set_by_name_changes_the_energy_by_what_it_weighs(affine_scene):
    # One model over two frames: its label cost is label_cost x the fundamental weight, and
    # nothing else in the energy depends on the weight.
    tracks, _ = affine_scene(sizes=(120, 90), noise=0.3, seed=6)
    one = np.zeros(tracks.shape[1], dtype=np.int64)
    half, _ = configs('model=fundamental', 'solver.fundamental_cost_weight=0.5')
    usual = dataclasses.replace(half, solver=SolverSettings())
    drop = (pearl.evaluate_segmentation(tracks[[0, -1]], one, usual, rng=0)[0]
            - pearl.evaluate_segmentation(tracks[[0, -1]], one, half, rng=0)[0])
    assert drop == pytest.approx(0.25 * usual.label_cost, rel=1e-9)
    # The affine subspace's cost scales with frames / affine_reference_frames.
    frames = tracks.shape[0]
    short, _ = configs(f'solver.affine_reference_frames={frames}')
    rise = (pearl.evaluate_segmentation(tracks, one, short, rng=0)[0]
            - pearl.evaluate_segmentation(tracks, one, PearlConfig(), rng=0)[0])
    assert rise == pytest.approx(PearlConfig().label_cost * (1 - frames / 30), rel=1e-9)


def test_a_growth_threshold_set_by_name_reaches_the_weights_of_a_fit(gap_scene):
    # One body in two clusters 300 px apart: with the long-edge threshold beyond every edge,
    # no unit grows, and the weights are those of a fit without growth.
    tracks, _ = gap_scene(same_body=True)
    far, _ = configs('solver.growth_from=1000000')
    plain = pearl._setting(tracks, PearlConfig(long_edge_growth=1.0), np.random.default_rng(0))
    usual = pearl._setting(tracks, PearlConfig(), np.random.default_rng(0))
    unset = pearl._setting(tracks, far, np.random.default_rng(0))
    assert not np.array_equal(usual.weights, plain.weights)
    assert np.array_equal(unset.weights, plain.weights)


@pytest.mark.parametrize('every', [1, 4])
def test_the_online_segmenter_estimates_the_noise_scale_as_often_as_set(monkeypatch, every):
    calls = []

    def spy(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    real = module.noise_scale
    monkeypatch.setattr(module, 'noise_scale', spy)
    frames = list(synthetic_stream(120, 9, (BodySpec(0.4),), seed=13))
    config, online = configs(f'solver.rescale_every={every}', 'budget_ms=0')
    segmenter = OnlineSegmenter(config, online)
    models = [segmenter.process(f.stamp_ns, f.ids, f.uv).model for f in frames]
    # Each model family keeps its own scale, estimated on its first fitted frame and then every
    # ``every`` frames it is fitted in.
    fitted = {name: models.count(name) for name in set(models) - {''}}
    assert fitted['affine'] >= 6
    assert len(calls) == sum(-(-count // every) for count in fitted.values())
