"""The sliding window's track keys against a dictionary oracle."""

from __future__ import annotations

import numpy as np

from pearl_ros.online.window import SlidingWindow, lookup


def test_lookup_agrees_with_a_dictionary():
    rng = np.random.default_rng(0)
    keys = np.unique(rng.integers(0, 1000, 300))
    values = rng.integers(-5, 50, keys.size)
    table = dict(zip(keys.tolist(), values.tolist(), strict=True))
    queries = rng.integers(-10, 1010, 500)
    expected = [table.get(q, -99) for q in queries.tolist()]
    assert lookup(keys, values, queries, -99).tolist() == expected
    assert lookup(keys[:0], values[:0], queries, -99).tolist() == [-99] * queries.size


def test_tracks_keep_their_keys_and_an_id_that_comes_back_is_a_new_track():
    # Oracle: a track is an unbroken run of an id; its key is fixed at its first frame, new
    # tracks numbered in input order after every earlier one.
    rng = np.random.default_rng(1)
    window = SlidingWindow(4)
    key_of: dict[int, int] = {}
    next_key = 0
    for frame in range(30):
        ids = rng.permutation(rng.choice(60, size=rng.integers(10, 40), replace=False))
        expected = []
        for ident in ids.tolist():
            if ident not in key_of:
                key_of[ident] = next_key
                next_key += 1
            expected.append(key_of[ident])
        key_of = {ident: key_of[ident] for ident in ids.tolist()}  # the rest ended
        keys = window.push(frame, ids, rng.normal(size=(ids.size, 2)))
        assert keys.tolist() == expected
    assert len(window) == 4
