"""One typed configuration object for PEaRL; every default is written here once.

Each field carries its description, unit and range as dataclass metadata, so that one check
validates it here and the ROS node declares its parameters (descriptions, ranges) from the same
source (:func:`parameter_specs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from pearl_ros.core.errors import InputError

MODEL_NAMES = ('affine', 'fundamental', 'homography')


def spec(default: Any, doc: str, *, low: float | None = None, high: float | None = None,
         choices: tuple[str, ...] | None = None) -> Any:
    """A dataclass field with its description and allowed range (``low <= value <= high``)."""
    return field(default=default, metadata={'doc': doc, 'low': low, 'high': high,
                                            'choices': choices})


@dataclass(frozen=True)
class ParameterSpec:
    """What a user-facing parameter is: name, default, type, description and range."""

    name: str
    default: Any
    type: type
    doc: str
    low: float | None
    high: float | None
    choices: tuple[str, ...] | None


def parameter_specs(cls: type) -> tuple[ParameterSpec, ...]:
    """The :class:`ParameterSpec` of every field of a configuration dataclass ``cls``."""
    return tuple(
        ParameterSpec(f.name, f.default, type(f.default), f.metadata['doc'], f.metadata['low'],
                      f.metadata['high'], f.metadata['choices'])
        for f in fields(cls))


def check_value(item: ParameterSpec, value: Any) -> None:
    """Raise InputError naming ``item`` if ``value`` is of the wrong type or out of range."""
    # bool is an int subclass, and an int is an acceptable float: compare the kinds users see.
    kind_ok = (isinstance(value, bool) if item.type is bool
               else isinstance(value, (int, float)) and not isinstance(value, bool)
               if item.type is float
               else isinstance(value, item.type) and not isinstance(value, bool))
    if not kind_ok:
        raise InputError(f'{item.name} must be of type {item.type.__name__}, got {value!r}')
    if item.choices is not None and value not in item.choices:
        raise InputError(f'{item.name} must be one of {item.choices}, got {value!r}')
    if item.low is not None and not value >= item.low:
        raise InputError(f'{item.name} must be >= {item.low}, got {value!r}')
    if item.high is not None and not value <= item.high:
        raise InputError(f'{item.name} must be <= {item.high}, got {value!r}')


def check_fields(config: Any) -> None:
    """Raise InputError naming the first field of ``config`` of the wrong type or out of range."""
    for item in parameter_specs(type(config)):
        check_value(item, getattr(config, item.name))


@dataclass(frozen=True)
class PearlConfig:
    """Parameters of the PEaRL energy and its optimiser (Isack & Boykov, IJCV 2012).

    The energy is ``E(L, f) = sum_p D_p(f_p) + sum_pq V_pq [f_p != f_q] + beta * |L(f)|``
    with ``D_p(l) = r_p(l)^2 / sigma_l^2 + 2 dof log(sigma_l / sigma_min)`` (residual ``r`` and
    each model's noise level ``sigma_l`` in pixels), a constant outlier cost, and Delaunay
    neighbours weighted by how alike they move: ``V_pq = lambda w_pq - mu (1 - w_pq)``, with
    ``w_pq`` near 1 for neighbours whose trajectories lie in each other's local 3-D affine
    subspace and near 0 for neighbours that miss it by many units (the noise level, or the
    ``unit_quantile`` quantile of the misses if larger, grown on long coherent edges by up to
    ``long_edge_growth``; :mod:`pearl_ros.core.contrast`). Cost
    units are those of D: one unit is a residual of one noise level.
    """

    model: str = spec('affine', 'motion model: affine | fundamental | homography',
                      choices=MODEL_NAMES)
    noise: float = spec(0.0, 'px, scale of inlier residuals; 0 = estimated from the data',
                        low=0.0, high=1e3)
    min_noise: float = spec(0.05, 'px, floor of the estimated noise scale', low=1e-6, high=1e3)
    outlier_threshold: float = spec(
        10.0, 'noise levels; a larger residual makes a point an outlier', low=1e-3, high=1e6)
    smoothness: float = spec(
        256.0, 'lambda, cost units per cut neighbour edge whose features move alike',
        low=0.0, high=1e6)
    separation: float = spec(
        50.0, 'mu, cost units earned per cut neighbour edge whose features move apart',
        low=0.0, high=1e6)
    contrast: float = spec(
        10.0, 'units (noise level, or the unit_quantile miss if larger) by which neighbours '
        "that move apart miss each other's local subspace",
        low=1e-3, high=1e6)
    unit_quantile: float = spec(
        0.6, "share of neighbour pairs whose miss is within the contrast unit (when the "
        'noise level is below it)', low=0.0, high=1.0)
    long_edge_growth: float = spec(
        3.0, "most times the unit of a neighbour pair's miss grows with the pair's length beyond "
        '6 median edge lengths, where the two ends move coherently (1 = never)',
        low=1.0, high=100.0)
    label_cost: float = spec(600.0, 'beta, cost units per motion model in use',
                             low=0.0, high=1e9)
    num_proposals: int = spec(200, 'fresh minimal samples per proposal round', low=1, high=100000)
    local_sampling: float = spec(
        0.8, "share of samples drawn from a point's image neighbourhood (NAPSAC)",
        low=0.0, high=1.0)
    max_iterations: int = spec(10, 'expand / re-estimate iterations per proposal round',
                               low=1, high=10000)
    rounds: int = spec(3, 'proposal rounds: best models so far mixed with fresh samples',
                       low=1, high=1000)

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
