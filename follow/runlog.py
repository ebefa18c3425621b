"""JSON-lines run log: one header line, then one line per processed frame.

The log holds what a person needs to see what the robot saw and did (skeletons, tracks,
target, command, timings), and what `follow run --replay` needs to re-run tracking and
identification on the same detections without the pose network.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from follow.types import (
    NUM_KEYPOINTS,
    Odometry,
    Skeleton,
    TargetEstimate,
    TrackState,
    VelocityCommand,
)

LOG_VERSION = 1
# The latest frame stamp a log may hold (about the year 5138): a hand-edited 1e300 passed
# as a finite number and overflowed the tracker's motion model (dt ** 3) on replay.
MAX_STAMP_S = 1e11


def _num(x: float) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 4)


def skeleton_to_json(s: Skeleton) -> dict:
    return {
        "keypoints_px": [[_num(u), _num(v)] for u, v in s.keypoints_px],
        "confidences": [round(float(c), 4) for c in s.confidences],
        "score": round(float(s.score), 4),
    }


def skeleton_from_json(d: dict, name: str = "skeleton") -> Skeleton:
    """A skeleton as `skeleton_to_json` writes it; ValueError naming the field otherwise
    (a log or a bag's skeleton topic may be cut, edited or of another program)."""
    if not isinstance(d, dict):
        raise ValueError(f"{name} is {_shown(d)}, not a JSON object")
    for key in ("keypoints_px", "confidences"):
        if key not in d:
            raise ValueError(f"{name} has no {key!r}")
    points, conf = d["keypoints_px"], d["confidences"]
    if not isinstance(points, list) or len(points) != NUM_KEYPOINTS:
        raise ValueError(f"{name} keypoints_px is {_shown(points)}, not a list of "
                         f"{NUM_KEYPOINTS} [x, y]")  # fmt: skip
    kp = np.array([_numbers(p, f"{name} keypoints_px[{i}]", 2, missing_ok=True)
                   for i, p in enumerate(points)], float)  # fmt: skip
    confidences = _numbers(conf, f"{name} confidences", NUM_KEYPOINTS, missing_ok=True)
    score = _number(d.get("score", 0.0), f"{name} score")
    return Skeleton(kp, np.asarray(confidences, float), score)


def _shown(value) -> str:
    """A JSON value as a message quotes it: short, as it stands in the file."""
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ValueError(f"{name} is {_shown(value)}, not a finite number")
    return float(value)


def _numbers(value, name: str, count: int, missing_ok: bool = False) -> list[float]:
    """A list of `count` finite numbers (null, a missing value, read as NaN if allowed)."""
    if not isinstance(value, list) or len(value) != count:
        raise ValueError(f"{name} is {_shown(value)}, not a list of {count} numbers")
    return [np.nan if v is None and missing_ok else _number(v, f"{name}[{i}]")
            for i, v in enumerate(value)]  # fmt: skip


def _whole(value, name: str) -> int:
    if isinstance(value, bool) or not (
        isinstance(value, int) or isinstance(value, float) and value.is_integer()
    ):
        raise ValueError(f"{name} is {_shown(value)}, not a whole number")
    return int(value)


def track_to_json(t: TrackState) -> dict:
    return {
        "id": t.track_id,
        "confirmed": t.confirmed,
        "mean": [round(float(v), 4) for v in t.mean],
        "cov_diag": [round(float(v), 5) for v in np.diag(t.cov)],
        "observed": t.observation is not None,
    }


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a run log, as read back."""

    frame_index: int
    stamp_s: float
    robot: Odometry | None
    skeletons: list[Skeleton]
    tracks: list[dict]
    target_status: str
    target_id: int | None
    confidences: dict[int, float]
    command: VelocityCommand | None
    timing_ms: dict[str, float]


class RunLogWriter:
    """Writes the log line by line and flushes every line, so a crash loses nothing."""

    def __init__(self, path: str | Path, header: dict):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "w")
        except OSError as exc:
            raise OSError(f"cannot write the log {self.path}: {exc.strerror or exc}") from exc
        self._write({"log_version": LOG_VERSION, **header})

    def _write(self, obj: dict) -> None:
        try:
            self._fh.write(json.dumps(obj, separators=(",", ":")) + "\n")
            self._fh.flush()
        except OSError as exc:  # a full disk: say which file, not only the errno
            raise OSError(f"cannot write the log {self.path}: {exc.strerror or exc}") from exc

    def write_frame(
        self,
        frame_index: int,
        stamp_s: float,
        robot: Odometry | None,
        skeletons: list[Skeleton],
        tracks: list[TrackState],
        target: TargetEstimate | None,
        command: VelocityCommand | None,
        timing_ms: dict[str, float] | None = None,
    ) -> None:
        self._write(
            {
                "frame": frame_index,
                "stamp_s": round(float(stamp_s), 6),
                "robot": None
                if robot is None
                else [_num(robot.x_m), _num(robot.y_m), _num(robot.yaw_rad)],
                "skeletons": [skeleton_to_json(s) for s in skeletons],
                "tracks": [track_to_json(t) for t in tracks],
                "target": None
                if target is None
                else {
                    "status": target.status.value,
                    "id": target.target_id,
                    "confidences": {
                        str(k): round(float(v), 4) for k, v in target.confidences.items()
                    },
                },
                "command": None
                if command is None
                else [round(command.forward_mps, 4), round(command.yaw_rate_radps, 4)],
                "timing_ms": {k: round(float(v), 3) for k, v in (timing_ms or {}).items()},
            }
        )

    def close(self) -> None:
        """Flush and close; a failure (a full disk) names the log, whose file is closed
        all the same (Python closes it even when the last flush fails)."""
        if self._fh.closed:
            return
        try:
            self._fh.close()
        except OSError as exc:
            raise OSError(f"cannot write the end of the log {self.path}: "
                          f"{exc.strerror or exc}") from exc  # fmt: skip

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_run_log(path: str | Path) -> tuple[dict, Iterator[FrameRecord]]:
    """The header and an iterator over the frame records, which reads the log a line at a
    time as it is iterated (an hour's log is never held whole). The header and the first
    frame line are read here, so a file that is no run log is refused at once. A truncated
    last line (a run that was killed mid-write) is ignored; any other malformed line is an
    error naming it, raised when the iteration reaches it."""
    reading = _read(Path(path))
    header = next(reading)
    return header, reading


def _read(path: Path) -> Iterator:
    """The header, then the frame records, from one open file; the file is closed when
    the records end or the iterator is dropped."""
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise OSError(f"run log {path}: {exc.strerror or exc}") from exc
    with fh:
        lines = _lines(fh, path)
        first = next(lines, None)
        if first is None:
            raise ValueError(f"run log {path}: empty")
        header = _header(path, first[1])
        ahead = next(lines, None)  # the first frame line: a binary file fails here
        yield header
        if ahead is None:
            return
        for number, line in itertools.chain([ahead], lines):
            try:
                d = json.loads(line)
            except json.JSONDecodeError:
                if next(lines, None) is None:
                    return  # the last line, cut short
                raise ValueError(f"run log {path}: line {number} is not JSON") from None
            try:
                record = _record(d)
            except (KeyError, ValueError) as exc:
                raise ValueError(f"run log {path}: line {number}: {_problem(exc)}") from None
            yield record


def _lines(fh, path: Path) -> Iterator[tuple[int, str]]:
    """The numbered lines of a file opened in binary, split as `str.splitlines` splits
    the whole text (a chunk read up to b"\\n" holds whole UTF-8 characters); bytes that are
    not UTF-8 are named by their offset in the file."""
    number, offset = 1, 0
    for chunk in fh:
        try:
            text = chunk.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(
                f"run log {path}: not a text run log (JSON lines; not UTF-8 at byte "
                f"{offset + exc.start})"
            ) from None
        offset += len(chunk)
        for line in text.splitlines():
            yield number, line
            number += 1


def _header(path: Path, line: str) -> dict:
    try:
        header = json.loads(line)
    except json.JSONDecodeError as exc:
        raise ValueError(f"run log {path}: line 1 (header) is not JSON ({exc})") from None
    if not isinstance(header, dict):
        raise ValueError(f"run log {path}: line 1 (header) is not a JSON object")
    version = header.get("log_version")
    if version != LOG_VERSION or isinstance(version, bool):
        shown = f"{version!r} (text, not a number)" if isinstance(version, str) else version
        raise ValueError(f"run log {path}: unsupported log_version {shown}; this version of "
                         f"follow reads log_version {LOG_VERSION}")  # fmt: skip
    size = header.get("image_size")
    if size is not None and not _is_image_size(size):
        raise ValueError(f"run log {path}: header image_size {size!r} is not [width, height] "
                         "in pixels")  # fmt: skip
    return header


def _is_image_size(size) -> bool:
    return (isinstance(size, list) and len(size) == 2
            and all(type(v) is int and v > 0 for v in size))  # fmt: skip


def _record(d: dict) -> FrameRecord:
    """One frame line, parsed; KeyError for a missing key, ValueError naming the field
    that is of the wrong shape."""
    if not isinstance(d, dict):
        raise ValueError(f"a frame record must be a JSON object, got {_shown(d)}")
    stamp_s = _stamp(d["stamp_s"])
    frame = _whole(d["frame"], "frame")
    skeletons = d["skeletons"]
    if not isinstance(skeletons, list):
        raise ValueError(f"skeletons is {_shown(skeletons)}, not a list")
    robot = d.get("robot")
    target = d.get("target") or {}
    if not isinstance(target, dict):
        raise ValueError(f"target is {_shown(target)}, not a JSON object")
    command = d.get("command")
    return FrameRecord(
        frame_index=frame,
        stamp_s=stamp_s,
        robot=None if robot is None else Odometry(*_numbers(robot, "robot", 3), stamp_s),
        skeletons=[skeleton_from_json(s, f"skeletons[{i}]")  # replayed: never assumed
                   for i, s in enumerate(skeletons)],  # fmt: skip
        tracks=_of_type(d.get("tracks", []), list, "tracks"),
        target_status=_of_type(target.get("status", ""), str, "target status"),
        target_id=_target_id(target.get("id")),
        confidences=_confidences(target.get("confidences", {})),
        command=None if command is None
        else VelocityCommand(*_numbers(command, "command", 2), stamp_s),
        timing_ms=_of_type(d.get("timing_ms", {}), dict, "timing_ms"),
    )


def _stamp(value) -> float:
    """A frame's time in seconds, in the range a clock gives (see MAX_STAMP_S)."""
    stamp_s = _number(value, "stamp_s")
    if not 0 <= stamp_s < MAX_STAMP_S:
        raise ValueError(f"stamp_s is {_shown(value)}, not a time from 0 to {MAX_STAMP_S:g} s")
    return stamp_s


def _of_type(value, kind: type, name: str):
    if not isinstance(value, kind):
        expected = {list: "a list", str: "text", dict: "a JSON object"}[kind]
        raise ValueError(f"{name} is {_shown(value)}, not {expected}")
    return value


def _target_id(value) -> int | None:
    return None if value is None else _whole(value, "target id")


def _confidences(value) -> dict[int, float]:
    """The target's confidence per track: a JSON object keyed by track id."""
    _of_type(value, dict, "target confidences")
    confidences = {}
    for key, v in value.items():
        try:
            track_id = int(key)
        except ValueError:
            raise ValueError(f"target confidences key {key!r} is no track id") from None
        confidences[track_id] = _number(v, f"target confidences[{key!r}]")
    return confidences


def _problem(exc: Exception) -> str:
    if isinstance(exc, KeyError):
        return f"frame record without the key {exc.args[0]!r}"
    return f"malformed frame record ({exc})"
