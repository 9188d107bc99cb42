"""Motion models, picked by name from one registry (as rosbags picks storage plugins)."""

from __future__ import annotations

from importlib import import_module

from pearl_ros.core.config import SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.models.base import MotionModel

# name -> (module, class); imported on first use so a model's dependencies load only when used.
REGISTRY: dict[str, tuple[str, str]] = {
    'affine': ('pearl_ros.core.models.affine', 'AffineSubspace'),
    'fundamental': ('pearl_ros.core.models.fundamental', 'Fundamental'),
    'homography': ('pearl_ros.core.models.homography', 'Homography'),
}


def get_model(name: str, settings: SolverSettings | None = None) -> MotionModel:
    """A new instance of the model registered as ``name``, tuned by ``settings`` (its label cost
    weight, refit caps; the defaults of :class:`SolverSettings` if None)."""
    try:
        module, cls = REGISTRY[name]
    except KeyError:
        raise InputError(f'unknown model {name!r}; known: {sorted(REGISTRY)}') from None
    model: MotionModel = getattr(import_module(module), cls)(settings)
    return model


__all__ = ['REGISTRY', 'MotionModel', 'get_model']
