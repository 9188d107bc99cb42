"""Parameters of the streaming layer, and ``NAME=VALUE`` settings shared by every front end.

The one settings builder: :func:`parse_assignments` types ``NAME=VALUE`` strings,
:func:`build_configs` turns a name -> value mapping (from those, a YAML file or ROS parameters)
into :class:`~pearl_ros.core.config.PearlConfig` and :class:`OnlineConfig`. Names are the user
parameters (:func:`user_names`) and the solver settings as ``solver.NAME``
(:func:`solver_names`); an unknown name is refused with the closest known one.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from pearl_ros.core.config import (
    ParameterSpec,
    PearlConfig,
    check_fields,
    parameter_specs,
    solver_specs,
    spec,
)
from pearl_ros.core.errors import InputError

TWO_VIEW_MODELS = ('fundamental', 'homography')


@dataclass(frozen=True)
class OnlineConfig:
    """How frames are windowed and how much PEaRL runs per frame.

    The energy itself (noise, label cost, smoothness, the model family) is :class:`PearlConfig`.
    """

    window: int = spec(15, 'frames in the sliding window (the newest included)', low=2, high=1000)
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
    continued_label_cost: float = spec(
        0.5, "share of label_cost a motion of the previous frame pays to go on (warm start "
        'only; a fresh motion pays all of it): a motion is harder to start than to keep',
        low=0.0, high=1.0)
    budget_ms: float = spec(
        20.0, 'ms, per-frame time budget, the answer included (the optimiser stops early '
        'enough for the work after it, publishing in the node, and for its last step); 0 = '
        'none. When it bites, labels depend on the '
        'machine; the first fit (and the first after a reset) then runs over the frames it '
        'takes, answering with its labels so far', low=0.0, high=1e6)
    max_fitted: int = spec(
        0, 'most features the optimiser segments per frame; the others whose tracks span '
        "the fitted frames go to the model of least data cost (0 = no limit)",
        low=0, high=10**9)
    min_coverage: float = spec(
        0.5, "share of a frame's features that must span the frames the models are fitted over",
        low=0.0, high=1.0)
    long_span: int = spec(
        10, 'fits span more frames than this only where long_coverage of the features span '
        'them: a longer span tells rigid motions apart better where tracks last, and leaves '
        'more young tracks unfitted where they churn', low=2, high=1000)
    long_coverage: float = spec(
        0.8, "share of a frame's features that must span a fit longer than long_span frames",
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
# Solver settings are named ``solver.NAME`` wherever parameters are given by name (--set, files).
SOLVER_PREFIX = 'solver.'


def user_names() -> tuple[str, ...]:
    """The user parameters' names, in the order of :data:`CONFIG_CLASSES`' fields: what the ROS
    node declares (no solver settings)."""
    return tuple(item.name for cls in CONFIG_CLASSES for item in parameter_specs(cls))


def solver_names() -> tuple[str, ...]:
    """The solver settings' names as given by name: ``solver.max_passes``, ..."""
    return tuple(SOLVER_PREFIX + item.name for item in solver_specs())


def known_names() -> tuple[str, ...]:
    """Every name :func:`build_configs` accepts: :func:`user_names`, then :func:`solver_names`."""
    return user_names() + solver_names()


def unknown_parameter(name: str, known: Iterable[str] | None = None) -> InputError:
    """The one-line error for an unknown parameter ``name``, suggesting the closest of ``known``
    (:func:`known_names` if None): ``unknown parameter 'label_cots' (did you mean
    'label_cost'?)``."""
    known = known_names() if known is None else tuple(known)
    # Compared without the solver prefix, which would make any two solver names look alike (and
    # hides a user parameter given as a solver setting, or the other way round).
    full = {_bare(k): k for k in reversed(known)}
    close = difflib.get_close_matches(_bare(name), list(full), n=1)
    hint = f' (did you mean {full[close[0]]!r}?)' if close else ''
    return InputError(f'unknown parameter {name!r}{hint}')


def _bare(name: str) -> str:
    return name[len(SOLVER_PREFIX):] if name.startswith(SOLVER_PREFIX) else name


def _spec(name: str) -> ParameterSpec | None:
    """The spec of parameter ``name`` (a solver setting's under its ``solver.`` name)."""
    if name.startswith(SOLVER_PREFIX):
        specs, bare = solver_specs(), name[len(SOLVER_PREFIX):]
    else:
        specs, bare = tuple(i for cls in CONFIG_CLASSES for i in parameter_specs(cls)), name
    for item in specs:
        if item.name == bare:
            return dataclasses.replace(item, name=name)
    return None


def parse_value(name: str, text: str) -> Any:
    """The value of parameter ``name`` from its command-line ``text``.

    A tuple setting (``solver.proposal_levels``) is written comma-separated: ``1,2,4``.
    """
    item = _spec(name)
    if item is None:
        raise unknown_parameter(name)
    text = text.strip()
    try:
        if item.type is bool:
            lowered = text.lower()
            if lowered not in ('true', 'false', '1', '0', 'yes', 'no'):
                raise ValueError(text)
            return lowered in ('true', '1', 'yes')
        if item.type is tuple:
            return tuple(float(part) for part in text.split(','))
        return item.type(text) if item.type is not str else text
    except ValueError as err:
        kind = 'comma-separated numbers' if item.type is tuple else item.type.__name__
        raise InputError(f'invalid value for {name}: {text!r} is not {kind}') from err


def split_assignment(item: str) -> tuple[str, str]:
    """``'NAME=VALUE'`` -> ``(NAME, VALUE)``, the name stripped; InputError if malformed."""
    name, sep, text = item.partition('=')
    name = name.strip()
    if not sep or not name:
        raise InputError(f'expected NAME=VALUE, got {item!r}')
    return name, text


def parse_assignments(items: Iterable[str]) -> dict[str, Any]:
    """``NAME=VALUE`` strings to a mapping of typed parameter values."""
    out: dict[str, Any] = {}
    for item in items:
        name, text = split_assignment(item)
        out[name] = parse_value(name, text)
    return out


def build_configs(values: Mapping[str, Any], base: tuple[PearlConfig, OnlineConfig] | None = None
                  ) -> tuple[PearlConfig, OnlineConfig]:
    """Both configuration objects from ``values`` (parameter name -> value) over ``base``.

    Names are those of :func:`known_names`: user parameters, and solver settings as
    ``solver.NAME``, which replace those of ``base``'s ``PearlConfig.solver``. An int given for
    a float parameter (YAML's ``label_cost: 1000``) is that float; a list for a tuple setting is
    that tuple.

    Raises
    ------
    InputError
        On an unknown name (suggesting the closest known one), or a value of the wrong type or
        out of range (naming it).
    """
    config, online = base or (PearlConfig(), OnlineConfig())
    for name in sorted(values):
        if _spec(name) is None:
            raise unknown_parameter(name)
    typed = {name: _coerce(_spec(name), value) for name, value in values.items()}
    solver = {name[len(SOLVER_PREFIX):]: value for name, value in typed.items()
              if name.startswith(SOLVER_PREFIX)}
    if solver:
        try:
            settings = dataclasses.replace(config.solver, **solver)
        except InputError as err:  # its messages start with the field's name
            raise InputError(f'{SOLVER_PREFIX}{err}') from err
        config = dataclasses.replace(config, solver=settings)
    return (dataclasses.replace(config, **_own(typed, PearlConfig)),
            dataclasses.replace(online, **_own(typed, OnlineConfig)))


def setting_values(config: PearlConfig, online: OnlineConfig) -> dict[str, Any]:
    """Every name of :func:`known_names` -> its value in ``config`` and ``online``: what
    :func:`build_configs` takes to build them again (a record of the settings a run used)."""
    values = {item.name: getattr(obj, item.name) for obj in (config, online)
              for item in parameter_specs(type(obj))}
    values.update({SOLVER_PREFIX + item.name: getattr(config.solver, item.name)
                   for item in solver_specs()})
    return values


def _own(values: Mapping[str, Any], cls: type) -> dict[str, Any]:
    """The entries of ``values`` that are user parameters of ``cls``."""
    names = {item.name for item in parameter_specs(cls)}
    return {name: value for name, value in values.items() if name in names}


def _coerce(item: ParameterSpec | None, value: Any) -> Any:
    """``value`` as parameter ``item`` holds it: an int as a float, a list as a tuple of floats."""
    def number(entry: Any) -> Any:
        return float(entry) if type(entry) is int else entry

    if item is not None and item.type is float:
        return number(value)
    if item is not None and item.type is tuple and isinstance(value, (list, tuple)):
        return tuple(number(entry) for entry in value)
    return value
