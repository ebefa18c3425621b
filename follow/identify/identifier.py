"""Which track is the person to follow: the target state machine, run frame by frame.

initial -> initial training -> tracking <-> re-identification

Each state is a small object in `follow.identify.states` whose `update` returns the next
state; their docstrings give the rules that move between them. This module checks the
configuration and each frame's input, keeps the current state and reports its estimate.

Rules every state shares (in `follow.identify.context`): only a track confirmed by the
tracker, seen in the current frame and in `min_target_observations` frames so far, can
become the target. A track's appearance is cut from the observation associated with it
in this frame; a track without one (occluded, missed) has no appearance and no
confidence this frame.
Nothing is learnt from a crop that shows two people: while another person's box (seen,
or predicted by the tracker) covers more than `max_learning_overlap` of the target's
box the frame is not learnt (neither the target nor the others), since learning during
a crossing would teach each person's appearance as the other's. Online boosting never
learns from the target alone: a frame with fewer than `min_negatives_per_update` other
people is topped up with recoloured copies of the target's crop.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from follow.ccf.features import FeatureExtractor, check_image
from follow.config import IdentifyConfig
from follow.identify.appearance import AppearanceModel
from follow.identify.context import FrameTracks, IdentityContext
from follow.identify.reid import ReidEmbedder
from follow.identify.states import Initial, State
from follow.types import InvalidInput, Odometry, TargetEstimate, TargetStatus, TrackState

log = logging.getLogger(__name__)

# A selected track id not among the tracks this long (frame stamps) while it is waited
# for is reported: a mistyped id, or a track already gone (ids are never reused),
# otherwise waits in silence (`follow run --target-id` passes its
# `[control] missing_target_warn_s`).
SELECTED_ID_MISSING_S = 5.0


class TargetIdentifier:
    """Learns the target's appearance online and says, per frame, which track it is."""

    def __init__(
        self,
        config: IdentifyConfig,
        extractor: FeatureExtractor | None,
        reid: ReidEmbedder | None = None,
    ):
        check_identify_config(config)
        self.config = config
        self.context = IdentityContext(config, AppearanceModel(config, extractor, reid))
        self._last: TargetEstimate | None = None  # the newest frame's estimate
        self._selection = SelectionWatch(None)
        self.reset()

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def model(self) -> AppearanceModel:
        return self.context.model

    @property
    def status(self) -> TargetStatus:
        return self.state.status

    @property
    def target_id(self) -> int | None:
        return self.state.target_id

    @property
    def selected_id_missing(self) -> bool:
        """The selected track id has not been among the tracks for `missing_warn_s` of
        frames while the identifier waits for it (never seen since its selection, or
        gone before it became the target: nothing is followed meanwhile); False once it
        appears, and while it is the target."""
        return self._selection.missing

    @property
    def last_stamp_s(self) -> float | None:
        """The stamp of the newest frame taken (one not newer is ignored)."""
        return None if self._last is None else self._last.stamp_s

    def reset(self) -> None:
        """Forget the target and everything learnt; a selected id stays requested. The
        newest frame's stamp stays (an older frame is still ignored), but its estimate
        names no target: it is what an ignored frame reports."""
        self.context.forget()
        self.context.observed_frames = {}
        self.context.last_frame_s = None  # the next frame follows no gap
        self.state: State = Initial()
        if self._last is not None:
            self._last = TargetEstimate(self.state.status, None, {}, self._last.stamp_s)

    def select_target(self, track_id: int, missing_warn_s: float = SELECTED_ID_MISSING_S) -> None:
        """Follow this track id: learning starts afresh on the next frame it is present.
        Not among the tracks for `missing_warn_s` of frames while it is waited for (since
        its selection, or since it was last seen before it became the target), it is
        warned of once (`selected_id_missing`); nobody else is chosen meanwhile."""
        if isinstance(track_id, bool) or not isinstance(track_id, int | np.integer):
            raise InvalidInput(f"select_target: track id {track_id!r} is not a whole number")
        if track_id < 0:
            raise InvalidInput(f"select_target: track id {track_id} is negative: no track's")
        self.context.requested_id = int(track_id)
        self._selection = SelectionWatch(int(track_id), missing_warn_s)
        self.reset()

    def select_nearest(self) -> None:
        """Forget any selected id and the target: the nearest person is chosen afresh."""
        self.context.requested_id = None
        self._selection = SelectionWatch(None)
        self.reset()

    def required_similarity(self, stamp_s: float) -> float:
        """The re-id similarity a candidate needs at `stamp_s` (see IdentityContext)."""
        return self.context.required_similarity(stamp_s)

    def required_confidence(self, stamp_s: float) -> float:
        """The confidence a candidate needs at `stamp_s` (see IdentityContext)."""
        return self.context.required_confidence(stamp_s)

    def update(
        self,
        image_bgr: np.ndarray,
        tracks: Sequence[TrackState],
        stamp_s: float,
        robot: Odometry | None = None,
    ) -> TargetEstimate:
        """One frame: the tracks of the tracker (with this frame's observations)."""
        check_image(image_bgr, "identifier image")
        if not math.isfinite(stamp_s):
            raise InvalidInput(f"identifier stamp_s is not finite: {stamp_s}")
        by_id = {t.track_id: t for t in tracks}
        if len(by_id) != len(tracks):
            raise InvalidInput("identifier: duplicate track ids in one frame")
        if self._last is not None and stamp_s <= self._last.stamp_s:
            # The tracker ignores such a frame (one stamped as the last is that frame again)
            # and hands on its previous tracks, with their observations: counting or
            # learning them again, cut from this image, is wrong.
            log.warning("identifier: ignoring a frame stamped %.3f s, not after the last "
                        "(%.3f s)", stamp_s, self._last.stamp_s)  # fmt: skip
            return self._last
        self.context.count_observations(by_id)
        self.context.note_frame(stamp_s, robot)
        frame = FrameTracks(image_bgr, list(tracks), stamp_s, robot, by_id)
        self.context.forget_departed(frame)
        self.state = self.state.update(self.context, frame)
        self._selection.check(by_id, stamp_s, waiting=self.state.status == TargetStatus.INITIAL)
        target_id = self.state.target_id
        seen = target_id in by_id and by_id[target_id].observation is not None
        self._last = TargetEstimate(self.state.status, target_id, frame.confidences, stamp_s, seen)
        return self._last


class SelectionWatch:
    """Whether a selected track id is missing while the identifier waits for it: warns
    once when it has not been among the tracks for `warn_after_s` of frames in a row
    while nothing is followed (in the initial state). Its absence is timed from its
    first absent frame, so a track that appeared and was retired before it became the
    target (too short to be confirmed; lost in initial training) is reported as one never
    seen is: ids are never reused, and the identifier would wait for it in silence. Once
    the id is the target the watch rests (losing it is the states' to handle). Only
    reports: the identifier keeps waiting for that id and never chooses anyone else."""

    def __init__(self, track_id: int | None, warn_after_s: float = SELECTED_ID_MISSING_S):
        self.track_id = track_id
        self.warn_after_s = warn_after_s
        self.missing = False
        self._seen = False  # the id was among the tracks since its selection
        self._absent_since_s: float | None = None

    def check(self, by_id: dict[int, TrackState], stamp_s: float, waiting: bool) -> None:
        """One frame's tracks; `waiting`: the identifier follows nobody after it."""
        present = self.track_id in by_id
        self._seen = self._seen or present
        if self.track_id is None or present or not waiting:
            self.missing, self._absent_since_s = False, None
            return
        if self._absent_since_s is None:
            self._absent_since_s = stamp_s
        if not self.missing and stamp_s - self._absent_since_s >= self.warn_after_s:
            self.missing = True
            self._warn(by_id)

    def _warn(self, by_id: dict[int, TrackState]) -> None:
        """Say once that the id is missing, and since when: a mistyped id was never
        seen; one seen and gone was retired by the tracker, and will not come back."""
        since = "it was last seen" if self._seen else "its selection"
        in_view = [int(i) for i in sorted(by_id)]
        log.warning("selected track %d: not among the tracks %.1f s after %s (tracks now: "
                    "%s); nothing is followed until it appears", self.track_id,
                    self.warn_after_s, since, in_view)  # fmt: skip


def check_identify_config(config: IdentifyConfig) -> None:
    """Raise ValueError naming the first inconsistent state machine setting."""
    if config.initial_training_frames < 1 or config.reid_frames < 1:
        raise ValueError("initial_training_frames and reid_frames must be >= 1")
    if config.reid_confidence < config.id_switch_confidence:
        raise ValueError(
            f"reid_confidence ({config.reid_confidence}) must not be below "
            f"id_switch_confidence ({config.id_switch_confidence})"
        )
    if config.min_target_observations < 1 or config.min_negatives_per_update < 0:
        raise ValueError("min_target_observations must be >= 1, min_negatives_per_update >= 0")
    if not (
        -1.0 <= config.reid_accept_similarity <= config.reid_strict_similarity <= 1.0
        and config.reid_confidence <= config.reid_strict_confidence <= 1.0
        and config.reid_strict_after_s > 0.0
    ):
        raise ValueError(
            "need -1 <= reid_accept_similarity <= reid_strict_similarity <= 1, "
            "reid_confidence <= reid_strict_confidence <= 1 and reid_strict_after_s > 0, "
            f"got {config.reid_accept_similarity}, {config.reid_strict_similarity}, "
            f"{config.reid_strict_confidence}, {config.reid_strict_after_s}"
        )
    if config.reid_reach_m < 0.0 or config.reid_reach_speed_mps < 0.0:
        raise ValueError("reid_reach_m and reid_reach_speed_mps must be >= 0")
    if config.reid_margin < 0.0 or not 0.0 <= config.max_learning_overlap <= 1.0:
        raise ValueError(
            f"reid_margin ({config.reid_margin}) must be >= 0 and max_learning_overlap "
            f"({config.max_learning_overlap}) in [0, 1]"
        )
