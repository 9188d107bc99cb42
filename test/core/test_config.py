"""The configuration objects: user parameters apart from the solver's settings, ranges checked."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from pearl_ros.core.config import PearlConfig, SolverSettings, parameter_specs, solver_specs
from pearl_ros.core.errors import InputError

USER_NAMES = ('model', 'noise', 'min_noise', 'outlier_threshold', 'smoothness', 'separation',
              'contrast', 'unit_quantile', 'long_edge_growth', 'label_cost', 'num_proposals',
              'local_sampling', 'max_iterations', 'rounds')


def test_pearl_config_specs_are_the_user_parameters_only():
    assert tuple(item.name for item in parameter_specs(PearlConfig)) == USER_NAMES
    assert PearlConfig.field_names() == USER_NAMES
    assert isinstance(PearlConfig().solver, SolverSettings)


def test_every_solver_setting_has_a_documented_default_within_its_range():
    specs = solver_specs()
    assert {item.name for item in specs} == {f.name for f in dataclasses.fields(SolverSettings)}
    for item in specs:
        assert item.doc
        values = item.default if isinstance(item.default, tuple) else (item.default,)
        for value in values:
            assert item.low is None or value >= item.low, item.name
            assert item.high is None or value <= item.high, item.name


@pytest.mark.parametrize('item', [s for s in solver_specs() if s.low is not None],
                         ids=lambda s: s.name)
def test_a_solver_setting_below_its_range_is_refused_naming_it(item):
    if item.type is int:
        value = int(item.low) - 1
    else:
        below = item.low - 1e-3 * max(abs(item.low), 1.0)
        value = (below,) if item.type is tuple else below
    with pytest.raises(InputError, match=rf'^{item.name} must be >= '):
        SolverSettings(**{item.name: value})


@pytest.mark.parametrize('name, value, message', [
    ('max_passes', 1001, 'max_passes must be <= 1000'),
    ('split_share_max', 1.5, 'split_share_max must be <= 1.0'),
    ('patch_size', 8.0, 'patch_size must be of type int'),
    ('stranger', float('nan'), 'stranger must be >= 1.0'),
    ('proposal_levels', [1.0, 2.0], 'proposal_levels must be a non-empty tuple'),
    ('proposal_levels', (), 'proposal_levels must be a non-empty tuple'),
    ('proposal_levels', (1.0, True), 'proposal_levels must be a non-empty tuple'),
    ('proposal_levels', (0.25, 1.0), r'proposal_levels must be >= sigma_floor \(0.5\)'),
    ('split_share_min', 0.95, r'split_share_min must be <= split_share_max \(0.9\)'),
    ('sigma_ceiling', 2.0, r'sigma_ceiling must be 0 or >= every proposal level \(4.0\)'),
])
def test_bad_solver_settings_are_refused_naming_the_field(name, value, message):
    with pytest.raises(InputError, match=message):
        SolverSettings(**{name: value})


def test_pearl_config_refuses_a_solver_that_is_not_solver_settings():
    with pytest.raises(InputError, match='solver must be a SolverSettings'):
        PearlConfig(solver={'patch_size': 8})


def test_equal_settings_make_equal_configs():
    assert PearlConfig(solver=SolverSettings(patch_size=9)) == PearlConfig(
        solver=SolverSettings(patch_size=9))
    assert PearlConfig(solver=SolverSettings(patch_size=9)) != PearlConfig()


def test_the_parameter_reference_lists_every_solver_setting_with_its_default():
    reference = (Path(__file__).resolve().parents[2] / 'docs' / 'parameters.md').read_text()
    for item in solver_specs():
        default = (','.join(f'{v:g}' for v in item.default) if isinstance(item.default, tuple)
                   else item.default)
        assert f'| `{item.name}` | `{default}` |' in reference, item.name
