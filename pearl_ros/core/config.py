"""Typed configuration of PEaRL; every default is written here once.

Two objects: :class:`PearlConfig`, the parameters a user tunes (the ROS node declares them), and
:class:`SolverSettings`, every tuned number of the solver itself (passes, patch sizes, weights,
caps), which experiments change with ``--set solver.NAME=VALUE`` but which are no ROS parameters.
Each field carries its description, unit and range as dataclass metadata, so that one check
validates it here and the front ends describe it from the same source (:func:`parameter_specs`,
:func:`solver_specs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from functools import cache
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
    """The :class:`ParameterSpec` of every scalar field of a configuration dataclass ``cls``.

    Fields made with :func:`spec` only: ``PearlConfig.solver`` (a :class:`SolverSettings`) is
    left out, so that the user parameters of ``PearlConfig`` are what this returns.
    """
    return tuple(
        ParameterSpec(f.name, f.default, type(f.default), f.metadata['doc'], f.metadata['low'],
                      f.metadata['high'], f.metadata['choices'])
        for f in fields(cls) if 'doc' in f.metadata)


def solver_specs() -> tuple[ParameterSpec, ...]:
    """The :class:`ParameterSpec` of every field of :class:`SolverSettings`."""
    return parameter_specs(SolverSettings)


def check_value(item: ParameterSpec, value: Any) -> None:
    """Raise InputError naming ``item`` if ``value`` is of the wrong type or out of range.

    A tuple parameter holds numbers, at least one, each within the range.
    """
    if item.type is tuple:
        if not isinstance(value, tuple) or not value or not all(map(_is_number, value)):
            raise InputError(f'{item.name} must be a non-empty tuple of numbers, got {value!r}')
        for entry in value:
            _check_range(item, entry)
        return
    # bool is an int subclass, and an int is an acceptable float: compare the kinds users see.
    kind_ok = (isinstance(value, bool) if item.type is bool
               else _is_number(value) if item.type is float
               else isinstance(value, item.type) and not isinstance(value, bool))
    if not kind_ok:
        raise InputError(f'{item.name} must be of type {item.type.__name__}, got {value!r}')
    if item.choices is not None and value not in item.choices:
        raise InputError(f'{item.name} must be one of {item.choices}, got {value!r}')
    _check_range(item, value)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_range(item: ParameterSpec, value: Any) -> None:
    if item.low is not None and not value >= item.low:
        raise InputError(f'{item.name} must be >= {item.low}, got {value!r}')
    if item.high is not None and not value <= item.high:
        raise InputError(f'{item.name} must be <= {item.high}, got {value!r}')


def check_fields(config: Any) -> None:
    """Raise InputError naming the first field of ``config`` of the wrong type or out of range."""
    for item in parameter_specs(type(config)):
        check_value(item, getattr(config, item.name))


@dataclass(frozen=True)
class SolverSettings:
    """Every tuned number of the solver (core and online), with its unit and range.

    These are not ROS parameters: the defaults are what the benchmarks were measured with, and an
    experiment changes one with ``--set solver.NAME=VALUE`` (``pearl_replay``, ``pearl_bench``).
    ``proposal_levels`` is a tuple, given on the command line comma-separated (``1,2,4``).

    Pure numerical tolerances stay module constants, since no experiment tunes them: the energy
    decrease that counts as progress (1e-9 cost units, :mod:`pearl_ros.core.pearl`), the rank
    tolerances of the models (``_RANK_TOL`` of :mod:`~pearl_ros.core.models.affine`,
    ``RANK_TOL`` of :mod:`~pearl_ros.core.models._twoview`, ``_COLLINEAR_TOL`` of
    :mod:`~pearl_ros.core.models.homography`), the coincident-points test of Hartley's
    normalisation, the finite-difference step ``_FD_STEP`` and the unmeasurable residual ``FAR``
    of the two-view models, and the guards against division by zero (1e-12).
    """

    # The search (pearl.py).
    max_passes: int = spec(5, 'expansion passes over the labels within one sweep',
                           low=1, high=1000)
    max_failed: int = spec(
        3, 'unused labels rejected in a row that end a sweep pass (labels go best gain first)',
        low=1, high=1000000)
    sigma_floor: float = spec(
        0.5, 'least noise level a model may claim, in units of the noise scale', low=1e-3,
        high=1.0)
    outlier_tie: float = spec(
        1.0, 'share of its weight a neighbour pair pays when cut with one end an outlier (1: '
        'plain Potts; below 0.5 the expansions of the outlier label truncate the pairs it '
        'breaks)', low=0.0, high=1.0)
    outlier_apart: bool = spec(
        True, 'an outlier earns the reward of every neighbour pair that moves apart, whatever '
        'its neighbour\'s label (each outlier its own motion)')
    isolation: float = spec(
        40.0, 'a point whose most alike neighbour misses it by more than this many times the '
        '10% quantile of such misses (and isolation_floor noise scales) is isolated: its '
        'outlier cost is that of a uniform density over the image, and it leaves the noise '
        'scale and the pair unit; 0 = off', low=0.0, high=1e6)
    isolation_floor: float = spec(
        5.0, 'noise scales: a point whose most alike neighbour misses it by less is never '
        'isolated', low=0.0, high=1e6)
    persist_deviations: float = spec(
        8.0, 'streaming: a track whose isolation (its least neighbour miss over the 10% '
        'quantile of such misses), averaged in log over its last window of frames, lies this '
        'many robust '
        'deviations (1.4826 median absolute deviations) above the median track is suspected '
        'isolated as the isolation test suspects a point; 0 = off', low=0.0, high=1e6)
    persist_frames: int = spec(
        5, 'streaming: frames of isolation a track needs before it can be suspected on them',
        low=1, high=1000000)
    persist_least: float = spec(
        3.0, 'streaming: least mean isolation (times the 10% quantile) of a track suspected '
        'on its past frames, so that no track is suspected where every track moves alike',
        low=1.0, high=1e6)
    persist_outliers: bool = spec(
        True, 'streaming: a track suspected on its past frames (persist_deviations) and rough '
        '(persist_roughness) is an outlier: isolated whatever its nearest miss, its outlier '
        'cost 0 and its ties to its neighbours dropped (the rewards of pairs that move apart '
        'stay), so that no model, however wide, holds it (off: it only stays out of the noise '
        'scale and the pair unit)')
    persist_roughness: float = spec(
        2.0, 'streaming: a suspected track is an outlier (persist_outliers) only where it is '
        'this many times rougher (RMS second difference of its positions over the window) '
        'than the median fitted track: a wandering outlier track is rough, a true track that '
        'perspective keeps apart from its neighbours is as smooth as the rest; 0 = every '
        'suspect', low=0.0, high=1e6)
    persist_rough_deviations: float = spec(
        5.0, 'streaming: a rough track (persist_roughness) is suspected on its past frames '
        'from this many robust deviations above the median track, where a smooth one needs '
        'persist_deviations: a rough track that stays apart from its neighbours is a '
        'wandering outlier track, where a true one is as smooth as its body; 0 = as '
        'persist_deviations', low=0.0, high=1e6)
    bridge_isolated: bool = spec(
        True, 'over three frames or more, and over two views with mismatches (where '
        'joint_neighbours applies), the points around isolated ones are also joined by the '
        'edges a Delaunay triangulation without the isolated points has, so that outlier '
        'tracks and mismatches do not cut the ties between the points of a body')
    joint_neighbours: float = spec(
        0.1, 'batch two-frame fits: where at least this share of the points keeps fewer than '
        'a third of its nearest image neighbours from one view to the other (mismatches), the '
        "isolation test reads each point's misses over patches drawn from its nearest "
        "neighbours in both views' coordinates together (x, y, x', y'): a mismatch lands "
        'anywhere in the second view, so the points around it there are not its neighbours '
        'in the first; 0 = never',
        low=0.0, high=1.0)
    kept_fellows: float = spec(
        0.25, 'where joint_neighbours applies: a model whose points keep less than this share '
        'of their 5 nearest fellow points (of the same model) from one view to the other, '
        'beyond what chance keeps ((s - c) / (1 - c), c = 5 / (M - 1) among M points), is no '
        'rigid motion but a model of mismatches, which land anywhere in the second view: its '
        'points become outliers at the end of each round; 0 = never',
        low=0.0, high=1.0)
    redraw_isolated: bool = spec(
        True, 'batch fits over three frames or more: once the isolated points are known, '
        "each point's patch is drawn again from its nearest image neighbours among the "
        "others, so that outlier tracks do not take the place of a body's points in their "
        "neighbours' patches, and a point stays isolated only where it still is on the new "
        'patches (the online segmenter keeps its patches: the isolated points change from '
        'frame to frame)')
    local_ceiling: float = spec(
        4.0, "batch two-view fits (fundamental matrices, homographies): a model's noise level "
        "is at most this many times its members' local noise, the median of their nearest "
        'misses (or the noise scale, or the pair unit, where larger), so that one model '
        'cannot take two structures, or a structure and the mismatches around it (4: the '
        'widest proposal level); 0 = off', low=0.0, high=1e6)
    static_contrast: float = spec(
        1.5, 'with known cameras: neighbours whose static-world residuals differ by d noise '
        'scales keep exp(-(d / static_contrast)^2) of their tie (a point that moves as the '
        'static world would and one that does not are not alike); 0 = ties as without cameras',
        low=0.0, high=1e6)
    interchangeable: float = spec(
        4.0, 'batch fits: once the search settles, two models each of which holds the '
        'other\'s points within this many of its own noise levels (the median point) are one '
        'motion and are merged, whatever the pair term says: its rewards for cutting neighbours '
        'that move apart otherwise keep a body cut in two along a depth discontinuity; 0 = off',
        low=0.0, high=1e6)
    interchangeable_online: float = spec(
        3.0, 'interchangeable, for the online fits of a stream (one frame\'s fit is short of '
        'search: duplicates of one motion it keeps go on to the next frames); 0 = off',
        low=0.0, high=1e6)
    sigma_ceiling: float = spec(
        0.0, 'most noise level a model may claim, in units of the noise scale; 0 = none',
        low=0.0, high=1e6)
    proposal_levels: tuple[float, ...] = spec(
        (1.0, 2.0, 4.0), 'noise levels a fresh hypothesis is offered at, in units of the noise '
        'scale (each >= sigma_floor; comma-separated on the command line)', low=1e-3, high=1e3)
    segment_samples: int = spec(
        20, 'minimal samples drawn inside each current segment per proposal round',
        low=0, high=100000)
    split_tries: int = spec(3, 'expand-and-refit (split) moves tried per iteration',
                            low=0, high=1000)
    split_screen: int = spec(60, 'unused labels, best gain bound first, screened for split moves',
                             low=1, high=1000000)
    split_share_min: float = spec(
        0.05, 'least share of a segment a split candidate must fit better than its model',
        low=0.0, high=1.0)
    split_share_max: float = spec(
        0.9, 'most share of a segment a split candidate may fit better than its model (more is '
        'a copy of the model, leaving nothing to refit)', low=0.0, high=1.0)
    # Neighbourhoods and the contrast term (neighbourhood.py, contrast.py).
    image_neighbours: int = spec(
        10, 'nearest image neighbours of a feature: local samples, contrast patches and noise '
        'scale neighbourhoods are drawn from them', low=1, high=1000)
    patch_size: int = spec(
        8, 'points of a local subspace fit of the contrast term: the point and its '
        'closest-moving image neighbours', low=2, high=1000)
    patch_core: int = spec(
        4, 'points of a patch always kept: the point and its closest-moving neighbours',
        low=2, high=1000)
    stranger: float = spec(
        5.0, 'a patch neighbour whose motion gap exceeds this many times that of the last core '
        'neighbour (with core_patches: whose distance to the core subspace exceeds this many '
        'times the second nearest one) is left out of the patch', low=1.0)
    core_patches: bool = spec(
        True, "batch fits over three frames or more: a patch's members beyond its core are the "
        "image neighbours nearest the core's affine subspace, not the closest-moving ones "
        '(two-view fits and the online segmenter keep the closest-moving patches)')
    core_patch_size: int = spec(
        9, 'points of a patch drawn around its core (core_patches)', low=2, high=1000)
    subspace_dim: int = spec(
        3, "affine dimension of a rigid body's trajectories: contrast patches, the coherence of "
        'long edges, and the motion subspaces that label young tracks', low=1, high=100)
    growth_from: float = spec(
        6.0, "median edge lengths beyond which a long coherent edge's unit grows",
        low=1.0, high=1e6)
    coherence: float = spec(
        2.0, "most ratio of the RMS residual of one subspace fitted to a long edge's two end "
        'neighbourhoods to that of their own fits, for its unit to grow', low=1.0, high=1e6)
    # Models and the noise scale (models/, scale.py).
    affine_reference_frames: int = spec(
        30, 'frames at which an affine subspace pays label_cost as configured (its cost '
        'scales with frames / this)', low=1, high=1000000)
    affine_cost_ceiling: float = spec(
        1.0, 'most factor on label_cost for an affine subspace, however many frames it spans '
        '(residuals are per-frame RMS distances, so a longer window does not raise a model\'s '
        'data gain in proportion); 0 = none', low=0.0, high=1e6)
    fundamental_cost_weight: float = spec(
        0.75, 'factor on label_cost for a fundamental matrix (one epipolar constraint per point '
        'is weaker evidence than a long subspace)', low=0.0, high=100.0)
    homography_cost_weight: float = spec(1.0, 'factor on label_cost for a homography',
                                         low=0.0, high=100.0)
    two_view_restarts: int = spec(
        3, 'batch two-view fits (fundamental matrices, homographies): fits from fresh draws '
        '(the noise scale\'s too), of which the lowest energy is kept: their searches end in '
        'different minima from seed to seed; the online segmenter\'s fits run once', low=1,
        high=1000)
    one_motion_restarts: int = spec(
        2, 'batch fits (two-view ones after their restarts) whose least energy is one motion '
        'for everything, its noise level wider than the widest proposal level: more fits from '
        'fresh draws, up to this many, until the least is not (the trap their searches fall '
        'into most); the online segmenter\'s fits run once', low=0, high=1000)
    fundamental_reweight_steps: int = spec(
        1, 'Sampson-reweighted linear fits of F after the first, when measuring the noise scale',
        low=0, high=100)
    lm_max_nfev: int = spec(
        50, 'residual evaluations per Levenberg-Marquardt refit of a two-view model',
        low=1, high=1000000)
    scale_seeds: int = spec(60, 'image neighbourhoods fitted to estimate the noise scale',
                            low=1, high=1000000)
    scale_trim: int = spec(
        0, 'points of each noise-scale neighbourhood left out as outliers (least trimmed '
        'squares); 0 = least squares over all', low=0, high=1000)
    # The online segmenter (online/segmenter.py).
    rescale_every: int = spec(15, 'frames between estimates of the noise scale when streaming',
                              low=1, high=1000000)
    young_min_age: int = spec(
        3, "frames a young track needs for its own trajectory to label it (fewer: its image "
        "neighbours' vote)", low=2, high=1000)
    subspace_members: int = spec(
        5, 'fitted members a motion needs to offer its subspace to young tracks',
        low=1, high=1000000)
    founding_scales: float = spec(
        5.0, 'streaming: a young track farther than this many noise scales (RMS per frame) '
        'from every motion\'s subspace is unexplained; where founding_tracks of them lie in '
        'one cluster of the image, the next fits span no more frames than they do, so that '
        'they can found a motion of their own (a new object); 0 = off', low=0.0, high=1e6)
    founding_tracks: int = spec(
        8, 'streaming: unexplained young tracks in one cluster, at least as old as their median, '
        'that cut the fitted span (founding_scales)', low=1, high=1000000)
    hold_motions: bool = spec(
        True, 'streaming: while young tracks cut the fitted span (founding_scales), a motion '
        'of the last frame that the cut fit merges away is given back to its tracks where a '
        'warm fit of the tracks that span up to long_span frames keeps it apart, and a motion '
        'it splits off is merged back where that fit joins it to another')
    energy_rise: float = spec(
        0.05, 'rise of the energy per feature, as a share, on a warm frame without proposals '
        'that makes the next frame propose', low=0.0, high=1e6)
    restart_motions: int = spec(
        2, 'streaming: a warm fit with fresh proposals that ends with at most this many '
        'motions is checked against a cold fit of the same tracks (the warm samples and '
        'rounds, no start labels), which it gives way to where that is lower in energy, the '
        'temporal cost of its labels counted: one wide motion refitted to a new object too, or '
        'to two objects an early fit joined, leaves no expansion a gain; 0 = never',
        low=0, high=1000000)

    def __post_init__(self) -> None:
        check_fields(self)
        if min(self.proposal_levels) < self.sigma_floor:
            raise InputError(f'proposal_levels must be >= sigma_floor ({self.sigma_floor}), '
                             f'got {self.proposal_levels!r}')
        if self.sigma_ceiling and self.sigma_ceiling < max(self.proposal_levels):
            raise InputError(f'sigma_ceiling must be 0 or >= every proposal level '
                             f'({max(self.proposal_levels)}), got {self.sigma_ceiling!r}')
        if self.split_share_min > self.split_share_max:
            raise InputError(f'split_share_min must be <= split_share_max '
                             f'({self.split_share_max}), got {self.split_share_min!r}')


@cache
def default_solver() -> SolverSettings:
    """The default :class:`SolverSettings`, built and checked once (it is frozen): code that
    runs every frame takes it where it is given none."""
    return SolverSettings()


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

    ``solver`` holds the solver's own tuned numbers (:class:`SolverSettings`); it is not a user
    parameter, and :func:`parameter_specs` leaves it out.
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
    # Not a user parameter: parameter_specs leaves it out (it has no spec metadata).
    solver: SolverSettings = field(default_factory=SolverSettings)

    def __post_init__(self) -> None:
        check_fields(self)
        if not isinstance(self.solver, SolverSettings):
            raise InputError(f'solver must be a SolverSettings, got {self.solver!r}')

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """The user parameters' names (``solver`` is not one)."""
        return tuple(item.name for item in parameter_specs(cls))
