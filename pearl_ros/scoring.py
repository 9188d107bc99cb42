"""Motion labels scored frame by frame against a bag's ground truth (ROS-free).

``pearl_play`` scores the labels ``pearl_node`` answers live, ``pearl_score`` the labels in an
output bag; both go through :func:`score_frame` and :func:`summarise`, and the misclassification
itself is :func:`pearl_ros.core.metrics.misclassification`.

Ground truth is read per frame (:func:`pearl_ros.bagio.reader.read_ground_truth_frames`) and a
frame's labels are scored against the truth message with the same header stamp, so features
that change motion over time (an object that starts or stops moving, a tracker that reuses an
id) are scored with the label of that frame. A frame whose stamp has no truth message is scored
against the truth merged over all frames, when no feature ever changes label there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pearl_ros.bagio import reader
from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER, num_motions
from pearl_ros.core.metrics import LabelIdentity, identities, misclassification

TRUTH_TOPIC = '/ground_truth/labels'
LABELS_TOPIC = '/motion_labels'

# One character per label: digits, then letters; '-' = not labelled, '?' = beyond 'z'.
_SYMBOLS = '0123456789abcdefghijklmnopqrstuvwxyz'


class GroundTruth:
    """Feature id -> true label, frame by frame.

    Parameters
    ----------
    frames : sequence of (int, (M,) int, (M,) int)
        ``(stamp_ns, ids, labels)`` per truth message, as
        :func:`~pearl_ros.bagio.reader.read_ground_truth_frames` returns them.
    """

    def __init__(self, frames: Sequence[tuple[int, np.ndarray, np.ndarray]]) -> None:
        self._by_stamp: dict[int, dict[int, int]] = {}
        merged: dict[int, int] | None = {}
        for stamp, ids, labels in frames:
            pairs = dict(zip(np.asarray(ids).tolist(), np.asarray(labels).tolist(), strict=True))
            self._by_stamp.setdefault(int(stamp), {}).update(pairs)
            if merged is not None:
                for feature, label in pairs.items():
                    if merged.setdefault(feature, label) != label:
                        merged = None  # labels change over time: per-frame lookups only
                        break
        self._merged = merged
        self.has_outliers = any(
            OUTLIER in frame.values() for frame in self._by_stamp.values())

    @classmethod
    def from_bag(cls, path: str | Path, topic: str = TRUTH_TOPIC) -> GroundTruth:
        """The ground truth of a bag.

        Raises
        ------
        BagError
            Missing or unreadable bag, no such topic, a malformed truth message.
        """
        return cls(reader.read_ground_truth_frames(path, topic))

    @property
    def frames(self) -> int:
        """Distinct stamps with a truth message."""
        return len(self._by_stamp)

    @property
    def changes_over_time(self) -> bool:
        """Some feature id has different labels in different frames."""
        return self._merged is None

    def at(self, stamp_ns: int) -> dict[int, int] | None:
        """Id -> label for the frame at ``stamp_ns`` (None when there is none to use)."""
        frame = self._by_stamp.get(int(stamp_ns))
        return frame if frame is not None else self._merged


@dataclass(frozen=True)
class FrameScore:
    """One frame's labels against its ground truth.

    Attributes
    ----------
    stamp_ns : int
        Header stamp of the labels, int nanoseconds.
    features : int
        Features in the labels message.
    labelled : int
        Of those, with a label other than -1.
    motions : int
        Distinct labels other than -1.
    scored : int
        Features that have ground truth in this frame (0: the frame is not scored).
    true_motions : int
        Distinct true labels other than -1 among the scored features.
    true_outliers : int
        Scored features the truth calls outliers (-1).
    outliers_found : int
        Of those, the ones labelled -1.
    error : float or None
        Misclassification rate of the scored features in [0, 1]
        (:func:`~pearl_ros.core.metrics.misclassification`; a feature labelled -1 that the
        truth puts in a motion counts as wrong); None when ``scored`` is 0.
    wrong : int
        Scored features labelled wrongly (``error * scored``).
    identities : tuple of (int, int)
        (true motion, label) pairs of the frame's one-to-one matching
        (:func:`~pearl_ros.core.metrics.identities`), for the identity switches over frames.
    """

    stamp_ns: int
    features: int
    labelled: int
    motions: int
    scored: int
    true_motions: int
    true_outliers: int
    outliers_found: int
    error: float | None
    wrong: int
    identities: tuple[tuple[int, int], ...] = ()


def score_frame(stamp_ns: int, ids: np.ndarray, labels: np.ndarray,
                truth: GroundTruth | None) -> FrameScore:
    """Score one frame's labels ``(N,)`` of features ``ids`` ``(N,)`` against ``truth``.

    Raises
    ------
    InputError
        Labels below -1 or shapes that do not match.
    """
    ids = np.asarray(ids, dtype=np.int64)
    labels = np.asarray(labels, dtype=np.int64)
    if ids.ndim != 1 or labels.shape != ids.shape:
        raise InputError(f'ids and labels must both have shape (N,), got {ids.shape} and '
                         f'{labels.shape}')
    labelled = labels != OUTLIER
    frame = truth.at(stamp_ns) if truth is not None else None
    known = np.fromiter((feature in frame for feature in ids.tolist()), dtype=bool,
                        count=ids.size) if frame else np.zeros(ids.size, dtype=bool)
    if frame is None or not known.any():
        return FrameScore(int(stamp_ns), int(ids.size), int(labelled.sum()),
                          num_motions(labels), 0, 0, 0, 0, None, 0)
    true = np.array([frame[feature] for feature in ids[known].tolist()], dtype=np.int64)
    pred = labels[known]
    error = misclassification(pred, true)
    return FrameScore(
        stamp_ns=int(stamp_ns), features=int(ids.size), labelled=int(labelled.sum()),
        motions=num_motions(labels), scored=int(known.sum()), true_motions=num_motions(true),
        true_outliers=int(np.count_nonzero(true == OUTLIER)),
        outliers_found=int(np.count_nonzero((true == OUTLIER) & (pred == OUTLIER))),
        error=error, wrong=int(round(error * true.size)),
        identities=tuple(sorted(identities(pred, true).items())),
    )


@dataclass(frozen=True)
class Summary:
    """Scores over a run: only frames that have labels and ground truth count.

    Attributes
    ----------
    frames : int
        Frames scored or not.
    unlabelled : list of int
        Indices of frames in which nothing was labelled (frame 0: a motion needs two frames).
    untruthed : int
        Frames with labels but no ground truth.
    counted : int
        Frames with labels and ground truth: the ones the figures below are over.
    overall : float or None
        Wrongly labelled features / scored features, over the counted frames.
    mean : float or None
        Mean of the counted frames' misclassification rates.
    last : float or None
        Misclassification of the last counted frame.
    motions_right : int
        Counted frames in which as many motions were found as the truth has.
    true_outliers, outliers_found : int
        Summed over the counted frames.
    switches : int
        Identity switches over the counted frames: a true motion matched to another label than
        the last one it was matched to (:class:`~pearl_ros.core.metrics.LabelIdentity`).
    """

    frames: int
    unlabelled: list[int]
    untruthed: int
    counted: int
    overall: float | None
    mean: float | None
    last: float | None
    motions_right: int
    true_outliers: int
    outliers_found: int
    switches: int = 0


def summarise(scores: Sequence[FrameScore]) -> Summary:
    """The :class:`Summary` of per-frame scores in frame order."""
    unlabelled = [index for index, row in enumerate(scores) if row.labelled == 0]
    counted = [row for row in scores if row.labelled > 0 and row.error is not None]
    untruthed = sum(row.labelled > 0 and row.error is None for row in scores)
    scored = sum(row.scored for row in counted)
    identity = LabelIdentity()
    for row in counted:
        identity.count(dict(row.identities))
    return Summary(
        frames=len(scores),
        unlabelled=unlabelled,
        untruthed=untruthed,
        counted=len(counted),
        overall=sum(row.wrong for row in counted) / scored if scored else None,
        mean=float(np.mean([row.error for row in counted])) if counted else None,
        last=counted[-1].error if counted else None,
        motions_right=sum(row.motions == row.true_motions for row in counted),
        true_outliers=sum(row.true_outliers for row in counted),
        outliers_found=sum(row.outliers_found for row in counted),
        switches=identity.switches,
    )


def percent(rate: float | None) -> str:
    """``rate`` as ``' 12.3%'`` (6 characters), ``'   n/a'`` for None."""
    return '   n/a' if rate is None else f'{100 * rate:5.1f}%'


def summary_lines(summary: Summary) -> list[str]:
    """The summary in words, a few lines for a person."""
    if summary.counted == 0:
        why = 'nothing was labelled' if len(summary.unlabelled) == summary.frames \
            else 'no labelled frame has ground truth'
        return [f'misclassification: n/a ({why})']
    lines = [
        f'misclassification over the {_count(summary.counted, "frame")} with labels and ground '
        'truth: '
        f'{percent(summary.overall).strip()} of their features,',
        f'  {percent(summary.mean).strip()} mean per frame, {percent(summary.last).strip()} on '
        'the last frame',
        f'motions: as many found as true in {summary.motions_right} of {summary.counted} frames',
        f'identity: {summary.switches} switch{"" if summary.switches == 1 else "es"} (a true '
        'motion matched to another label than the one it last had)',
    ]
    if summary.true_outliers:
        lines.append(f'outliers: {summary.outliers_found} of the {summary.true_outliers} '
                     'features the truth calls outliers were labelled -1')
    if summary.unlabelled:
        why = ''
        if summary.unlabelled[0] == 0:
            why = ' (a motion needs two frames: the first has none' + (
                '; under a time budget the first fit can take a few frames more)'
                if len(summary.unlabelled) > 1 else ')')
        lines.append(f'not counted: {_frames(summary.unlabelled)}, without labels{why}')
    if summary.untruthed:
        lines.append(f'not counted: {summary.untruthed} frame(s) without ground truth')
    return lines


def label_string(labels: np.ndarray, width: int = 0) -> str:
    """One character per label (``-`` for -1); cut at ``width`` characters with `` +N more``
    (``width`` 0: every label)."""
    text = ''.join('-' if k < 0 else _SYMBOLS[k] if k < len(_SYMBOLS) else '?'
                   for k in np.asarray(labels).tolist())
    if width <= 0 or len(text) <= width:
        return text
    return f'{text[:width]} +{len(text) - width} more'


def _count(number: int, noun: str) -> str:
    return f'{number} {noun}{"" if number == 1 else "s"}'


def _frames(indices: list[int]) -> str:
    shown = ', '.join(str(index) for index in indices[:10])
    more = f' and {len(indices) - 10} more' if len(indices) > 10 else ''
    return f'frame{"s" if len(indices) > 1 else ""} {shown}{more}'
