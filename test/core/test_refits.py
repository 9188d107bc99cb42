"""A setting computes each refit once.

A search asks for the same refit again and again: a merge candidate round after round while
neither segment changes, the losers of a split trial that the next refit step asks for again.
A refit depends only on the setting, its members and its start, so ``_refit_one`` keeps what
it computed (``_Setting.refits``, at most ``REFITS_KEPT`` of them). The oracle is the same fit
with nothing kept (``REFITS_KEPT`` 0): every result the same to the bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig


def _fits(tracks: np.ndarray, model: str, seed: int, monkeypatch: pytest.MonkeyPatch
          ) -> tuple[pearl.PearlResult, int]:
    """The fit, and how many refits it computed."""
    computed = 0
    compute = pearl._computed_refit

    def counted(*args):
        nonlocal computed
        computed += 1
        return compute(*args)

    monkeypatch.setattr(pearl, '_computed_refit', counted)
    result = pearl.fit(tracks, PearlConfig(model=model), np.random.default_rng(seed))
    monkeypatch.setattr(pearl, '_computed_refit', compute)
    return result, computed


def _same(a: pearl.PearlResult, b: pearl.PearlResult) -> None:
    assert np.array_equal(a.labels, b.labels)
    assert a.energy == b.energy
    assert np.array_equal(a.sigmas, b.sigmas)
    assert np.array_equal(np.asarray(a.params), np.asarray(b.params), equal_nan=True)


@pytest.mark.parametrize('seed', range(3))
def test_a_two_view_fit_is_the_same_with_its_refits_kept(two_view_scene, monkeypatch, seed):
    tracks, _ = two_view_scene(seed, mismatches=0.4)
    kept, fewer = _fits(tracks, 'fundamental', seed, monkeypatch)
    monkeypatch.setattr(pearl, 'REFITS_KEPT', 0)
    computed, every = _fits(tracks, 'fundamental', seed, monkeypatch)
    _same(kept, computed)
    assert fewer < every  # the search did ask for some refits again


@pytest.mark.parametrize('seed', range(3))
def test_an_affine_fit_is_the_same_with_its_refits_kept(affine_scene, monkeypatch, seed):
    tracks, _ = affine_scene(sizes=(60, 40, 30), seed=seed)
    kept, fewer = _fits(tracks, 'affine', seed, monkeypatch)
    monkeypatch.setattr(pearl, 'REFITS_KEPT', 0)
    computed, every = _fits(tracks, 'affine', seed, monkeypatch)
    _same(kept, computed)
    assert fewer < every  # the search did ask for some refits again


def _setting(tracks: np.ndarray) -> pearl._Setting:
    return pearl._setting(tracks, PearlConfig(model='fundamental'), np.random.default_rng(0))


def test_a_refit_asked_again_is_the_one_computed_and_cannot_be_changed(two_view_scene):
    tracks, truth = two_view_scene(0, mismatches=0.0)
    setting = _setting(tracks)
    members = np.flatnonzero(truth == 0)
    start = setting.model.fit_minimal(setting.data, members[None, :8])[0][0]
    first = pearl._refit_one(setting, members, start)
    again = pearl._refit_one(setting, members.copy(), start.copy())
    assert first is not None and again is first
    for array in (first[0], first[2], first[3]):
        with pytest.raises(ValueError):
            array[0] = 0.0
    # Other members, or another start, are another refit.
    other = pearl._refit_one(setting, members[:-1], start)
    assert other is not None and other is not first
    assert not np.array_equal(other[3], first[3])
    moved = pearl._refit_one(setting, members, -start)
    assert moved is not first


def test_a_setting_keeps_at_most_refits_kept(two_view_scene, monkeypatch):
    monkeypatch.setattr(pearl, 'REFITS_KEPT', 4)
    tracks, truth = two_view_scene(1, mismatches=0.0)
    setting = _setting(tracks)
    members = np.flatnonzero(truth == 0)
    start = setting.model.fit_minimal(setting.data, members[None, :8])[0][0]
    for drop in range(10):
        pearl._refit_one(setting, members[drop:], start)
        assert 1 <= len(setting.refits) <= 4
