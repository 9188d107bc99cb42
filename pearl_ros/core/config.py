"""One typed configuration object for PEaRL; every default is written here once."""

from __future__ import annotations

from dataclasses import dataclass, fields

from pearl_ros.core.errors import InputError

MODEL_NAMES = ('affine', 'fundamental', 'homography')


@dataclass(frozen=True)
class PearlConfig:
    """Parameters of the PEaRL energy and its optimiser (Isack & Boykov, IJCV 2012).

    The energy is ``E(L, f) = sum_p D_p(f_p) + lambda * sum_pq w_pq [f_p != f_q] + beta * |L(f)|``
    with ``D_p(l) = r_p(l)^2 / sigma_l^2 + 2 dof log(sigma_l / sigma_min)`` (residual ``r`` and
    each model's noise level ``sigma_l`` in pixels) and a constant outlier cost. Cost units are
    those of D: one unit is a residual of one noise level.
    """

    model: str = 'affine'  # motion model: affine | fundamental | homography
    noise: float = 0.0  # px, scale of inlier residuals; 0 = estimated from the data
    min_noise: float = 0.05  # px, floor of the estimated scale
    outlier_threshold: float = 10.0  # noise levels; a larger residual makes a point an outlier
    smoothness: float = 4.0  # lambda, cost units per cut neighbour edge of unit weight
    label_cost: float = 1000.0  # beta, cost units per model in use
    num_proposals: int = 200  # fresh minimal samples per proposal round
    local_sampling: float = 0.8  # share of samples drawn from a point's neighbourhood (NAPSAC)
    max_iterations: int = 10  # expand / re-estimate iterations per proposal round
    rounds: int = 3  # proposal rounds: best models so far mixed with fresh samples

    def __post_init__(self) -> None:
        if self.model not in MODEL_NAMES:
            raise InputError(f'model must be one of {MODEL_NAMES}, got {self.model!r}')
        positive = ('min_noise', 'outlier_threshold')
        for name in positive:
            value = getattr(self, name)
            if not value > 0:
                raise InputError(f'{name} must be > 0, got {value!r}')
        for name in ('noise', 'smoothness', 'label_cost'):
            value = getattr(self, name)
            if not value >= 0:
                raise InputError(f'{name} must be >= 0, got {value!r}')
        for name in ('num_proposals', 'max_iterations', 'rounds'):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise InputError(f'{name} must be an integer >= 1, got {value!r}')
        if not 0.0 <= self.local_sampling <= 1.0:
            raise InputError(f'local_sampling must be in [0, 1], got {self.local_sampling!r}')

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
