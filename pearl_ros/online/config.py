"""Parameters of the streaming layer, and ``NAME=VALUE`` settings shared by every front end."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from pearl_ros.core.config import PearlConfig, check_fields, parameter_specs, spec
from pearl_ros.core.errors import InputError

TWO_VIEW_MODELS = ('fundamental', 'homography')


@dataclass(frozen=True)
class OnlineConfig:
    """How frames are windowed and how much PEaRL runs per frame.

    The energy itself (noise, label cost, smoothness, the model family) is :class:`PearlConfig`.
    """

    window: int = spec(10, 'frames in the sliding window (the newest included)', low=2, high=1000)
    warm_start: bool = spec(True, "start each frame from the previous frame's models and labels")
    warm_proposals: int = spec(
        30, 'fresh minimal samples per warm-started frame (cold frames use num_proposals)',
        low=1, high=100000)
    warm_rounds: int = spec(1, 'proposal rounds per warm-started frame', low=1, high=1000)
    warm_unit_quantile: float = spec(
        0.5, 'unit_quantile of warm-started frames (cold frames use unit_quantile): a warm '
        'fit keeps the merges it made unless rewards for cutting pairs undo them',
        low=0.0, high=1.0)
    propose_every: int = spec(
        3, 'warm-started frames per batch of fresh proposals; the frames between only relabel '
        'and refit the current motions, unless the energy per feature rose 5% (1 = fresh '
        'proposals every frame)', low=1, high=1000)
    temporal_cost: float = spec(
        2.0, "cost units for a feature labelled other than its previous frame's motion (warm "
        'start only): a temporal Potts term against label flicker', low=0.0, high=1e6)
    budget_ms: float = spec(
        20.0, 'ms, per-frame time budget of the optimiser; 0 = none. When it bites, labels '
        'depend on the machine', low=0.0, high=1e6)
    min_coverage: float = spec(
        0.5, "share of a frame's features that must span the frames the models are fitted over",
        low=0.0, high=1.0)
    two_view_model: str = spec(
        'fundamental', 'model between the window ends when only two frames span enough '
        'features, or when model is a two-view one: fundamental | homography',
        choices=TWO_VIEW_MODELS)
    neighbours: int = spec(5, 'image neighbours that vote the label of a feature seen in one '
                           'frame only (or too young for a two-view fit)', low=1, high=100)
    seed: int = spec(0, 'seed of the proposal sampler; equal seeds and frames give equal labels',
                     low=0, high=2**63 - 1)

    def __post_init__(self) -> None:
        check_fields(self)


CONFIG_CLASSES = (PearlConfig, OnlineConfig)


def known_names() -> tuple[str, ...]:
    """Every parameter name, in the order of :data:`CONFIG_CLASSES`' fields."""
    return tuple(item.name for cls in CONFIG_CLASSES for item in parameter_specs(cls))


def parse_value(name: str, text: str) -> Any:
    """The value of parameter ``name`` from its command-line ``text``."""
    for cls in CONFIG_CLASSES:
        for item in parameter_specs(cls):
            if item.name != name:
                continue
            try:
                if item.type is bool:
                    lowered = text.strip().lower()
                    if lowered not in ('true', 'false', '1', '0', 'yes', 'no'):
                        raise ValueError(text)
                    return lowered in ('true', '1', 'yes')
                return item.type(text.strip()) if item.type is not str else text.strip()
            except ValueError as err:
                raise InputError(f'invalid value for {name}: {text!r} is not '
                                 f'{item.type.__name__}') from err
    raise InputError(f'unknown parameter {name!r} (known: {", ".join(known_names())})')


def parse_assignments(items: Iterable[str]) -> dict[str, Any]:
    """``NAME=VALUE`` strings to a mapping of typed parameter values."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition('=')
        name = name.strip()
        if not sep or not name:
            raise InputError(f'expected NAME=VALUE, got {item!r}')
        out[name] = parse_value(name, text)
    return out


def build_configs(values: Mapping[str, Any], base: tuple[PearlConfig, OnlineConfig] | None = None
                  ) -> tuple[PearlConfig, OnlineConfig]:
    """Both configuration objects from ``values`` (parameter name -> value) over ``base``.

    Raises
    ------
    InputError
        On an unknown name, or a value of the wrong type or out of range (naming it).
    """
    base = base or (PearlConfig(), OnlineConfig())
    unknown = sorted(set(values) - set(known_names()))
    if unknown:
        raise InputError(f'unknown parameter {unknown[0]!r} (known: {", ".join(known_names())})')
    out = []
    for config in base:
        names = {item.name for item in parameter_specs(type(config))}
        mine = {k: v for k, v in values.items() if k in names}
        # An int given for a float parameter (YAML's `label_cost: 1000`) is that float.
        for item in parameter_specs(type(config)):
            if item.name in mine and item.type is float and type(mine[item.name]) is int:
                mine[item.name] = float(mine[item.name])
        out.append(dataclasses.replace(config, **mine))
    return out[0], out[1]
