"""argparse types for counts and quantities: a value out of range is refused by
argparse with the option named (`argument --frames: expected an integer >= 1, got '0'`)
before any work is done, instead of failing deep inside an evaluation. Also what
`follow` and `follow-calib` alike say of bad input: camera indices, one-line errors, a
refused command line under `--json`."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import tempfile
from pathlib import Path

# The largest camera index a source may name: OpenCV takes a C int (which may add a
# back-end, 200 + n: V4L2).
MAX_CAMERA_INDEX = 2**31 - 1


# A video file's damaged frames: a failed read before the frame count the file's header
# announces is a damaged frame, skipped. `follow run` and `follow-calib` skip any number of
# them before a count that fits the file, and this many in a row where there is no such
# count (then the file counts as ended). Containers may count a frame more than they decode,
# so a file this much short ends without a warning.
MAX_UNDECODABLE_RUN = 30
EARLY_END_TOLERANCE_FRAMES = 1
# A file's announced frame count above its size in bytes over this is a damaged header, not a
# count (no container stores a frame in fewer: AVI's chunk header alone is 8 bytes); it does
# not bound a run of failed reads, which would be walked for hours (2**31 frames) at the end.
MIN_FILE_BYTES_PER_FRAME = 8


def frame_count_fits_file(path: str | Path, frame_count: int) -> bool:
    """Whether the frame count a video file's header announces could be stored in its
    bytes: a count to walk a damaged stretch of any length up to."""
    try:
        size = Path(path).stat().st_size
    except OSError:
        return False
    return 0 < frame_count and frame_count * MIN_FILE_BYTES_PER_FRAME <= size


def refuse_overwriting(inputs: dict, outputs: dict) -> None:
    """Refuse an output that is one of the inputs or another output, before anything is
    read or written (`follow run` and `follow-calib` alike): found after the work, the
    input is already lost. `inputs`: label -> path (None, empty or missing skipped);
    `outputs`: option -> path (None or empty skipped)."""
    seen: dict[Path, str] = {}
    for label, value in inputs.items():
        if value and Path(value).exists():
            seen[Path(value).resolve()] = label
    for name, value in outputs.items():
        if not value:
            continue
        path = Path(value).resolve()
        if path in seen:
            raise ValueError(f"{name} {value} is also the {seen[path]}: it would be overwritten")
        seen[path] = name


def refuse_unwritable(output: Path, name: str, why: str = "") -> None:
    """Refuse an output whose folder cannot be made or written in before the work that
    makes it (minutes of calibration or quantisation), not after. Missing folders are
    fine when the nearest existing one can be written in: the writer makes them. `name`
    is the option, `why` what is written there, for the message."""
    folder = Path(output).absolute().parent
    while not folder.exists():
        folder = folder.parent
    if not (folder.is_dir() and os.access(folder, os.W_OK | os.X_OK)):
        raise OSError(f"cannot write {output} ({name}): {folder} is not a folder that can be "
                      "written in" + (f"; {why}" if why else ""))  # fmt: skip


def refuse_non_utf8_name(path: str | os.PathLike, name: str) -> None:
    """Refuse a path whose name holds bytes that are not UTF-8 (a Latin-1 name from an
    old archive, held by Python as surrogates) before OpenCV is given it: its binding
    crashes the process on such a name (a segmentation fault, no error to report).
    `name` is the option, for the message."""
    text = os.fspath(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{name} {_shown_name(text)} is not a UTF-8 name; rename it") from None


def _shown_name(text: str) -> str:
    """A name as printable text: the bytes that are not UTF-8 written as `\\xe9`."""
    try:
        return os.fsencode(text).decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate no file name decodes to
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


# The namespace attribute holding, during one parse, the options already given a value.
_GIVEN = "_options_given"


class StoreOnce(argparse._StoreAction):
    """argparse's `store`, refusing an option given a value twice (`--config a.toml
    --config b.toml`): argparse keeps the last silently, so an override a script appends,
    or the value before it, would be dropped unseen. Positionals, flags (`-v -v` sets
    the same) and the accumulating actions (append, extend, count) are not concerned."""

    def __call__(self, parser, namespace, values, option_string=None):
        if self.option_strings:
            given = namespace.__dict__.setdefault(_GIVEN, set())
            if self.dest in given:
                raise argparse.ArgumentError(
                    self, "given more than once; give it once (the last would silently win)"
                )
            given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, whose refusal of a command line (a bad option value, an unknown
    option) also ends stdout with `{"error": ...}` when that command line asks for
    `--json`, as every other error does (`print_error`); it still exits with 2. An
    option that takes a value is refused when given twice (`StoreOnce`), in the
    commands' parsers too (made by `add_subparsers`)."""

    def __init__(self, *args, json_requested: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.json_requested = json_requested
        self.register("action", None, StoreOnce)
        self.register("action", "store", StoreOnce)

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        namespace.__dict__.pop(_GIVEN, None)  # bookkeeping of this parse only
        return namespace, extras

    def add_subparsers(self, **kwargs):
        kwargs.setdefault("parser_class", _parser_class(self.json_requested))
        return super().add_subparsers(**kwargs)

    def error(self, message: str):
        self.print_usage(sys.stderr)
        if self.json_requested:
            print(json.dumps({"error": message}), flush=True)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parser_class(json_requested: bool):
    return lambda **kwargs: ArgumentParser(json_requested=json_requested, **kwargs)


def camera_index_too_large(index_text: str) -> str | None:
    """Why a source of digits can name no camera, or None: `follow run` and
    `follow-calib` read camera indices alike and say the same of them."""
    if int(index_text) > MAX_CAMERA_INDEX:
        return f"no camera index is that large (at most {MAX_CAMERA_INDEX})"
    return None


def no_camera_at(index) -> str:
    """What to say of a camera index that OpenCV cannot open."""
    return (f"no camera at index {index} can be opened (ls /dev/video*: the index is the "
            "number after video)")  # fmt: skip


def _number(text: str, kind: type):
    try:
        value = kind(text)
    except ValueError:
        what = "an integer" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _at_least(kind: type, lowest, strict: bool, expected: str):
    """An argparse type: a `kind` number above `lowest` (or at least it)."""

    def parse(text: str):
        value = _number(text, kind)
        if value < lowest or (strict and value == lowest):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


def finite_float(text: str) -> float:
    """An argparse type: any number but NaN and the infinities."""
    return _number(text, float)


def float_within(lowest: float, highest: float, highest_open: bool = False):
    """An argparse type: a finite number from `lowest` to `highest` (below it, open)."""
    expected = f"a number from {lowest:g} to {'below ' if highest_open else ''}{highest:g}"

    def parse(text: str) -> float:
        value = _number(text, float)
        if not (lowest <= value < highest if highest_open else lowest <= value <= highest):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


def int_at_least(lowest: int):
    """An argparse type: an integer >= `lowest`."""
    return _at_least(int, lowest, False, f"an integer >= {lowest}")


def seed_number(text: str) -> int:
    """An argparse type: a random seed, an integer from 0 to 2**32 - 1 (numpy's range)."""
    value = _number(text, int)
    if not 0 <= value <= 2**32 - 1:
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to 2**32 - 1, got {text!r}")
    return value


positive_int = _at_least(int, 1, False, "an integer >= 1")
non_negative_int = _at_least(int, 0, False, "an integer >= 0")
positive_float = _at_least(float, 0.0, True, "a positive number")
non_negative_float = _at_least(float, 0.0, False, "a number >= 0")


def identifier_list(text: str) -> str:
    """An argparse type: comma-separated identifier names (`ccf10,ccf10+reid`), each one
    the identifier factory understands, at least one; the text is kept as given. An
    evaluation runs its identifiers in turn, so a misspelt one found only there fails
    after the others have run."""
    from follow.identify.factory import parse_identifier

    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r} names no identifier")
    for name in names:
        try:
            parse_identifier(name)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def picture_path(suffixes: tuple[str, ...], kind: type = str):
    """An argparse type for a picture to write once the work is done: its suffix and
    folder checked now, so that a typo does not throw the finished work away."""

    def parse(text: str):
        path = Path(text)
        if path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(
                f"{text!r}: a picture file is needed, ending in one of {', '.join(suffixes)}"
            )
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file name")
        folder = path.resolve().parent
        if folder.exists() and not folder.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r}: {path.parent} is a file, not a folder")
        if not folder.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r}: the folder {path.parent} does not exist")
        try:  # a read-only or virtual folder: found now, not after the work
            tempfile.TemporaryFile(dir=folder).close()
        except OSError as exc:
            raise argparse.ArgumentTypeError(
                f"{text!r}: the folder {path.parent} cannot be written ({exc.strerror or exc})"
            ) from None
        return kind(text)

    return parse


PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")  # what matplotlib writes here
plot_path = picture_path(PLOT_SUFFIXES)


# The libraries whose own exception classes (not ValueError or RuntimeError) report bad
# input: an image OpenCV cannot resize, a file onnxruntime cannot parse as a model, a
# topic name ROS 2 refuses.
_LIBRARIES_WITH_OWN_ERRORS = ("cv2", "onnxruntime", "rclpy")


def is_library_error(exc: BaseException) -> bool:
    """Whether `exc` is one of those libraries' own error classes: bad input met inside
    the library, to be reported in one line like any other (not a crash of ours)."""
    return type(exc).__module__.split(".")[0] in _LIBRARIES_WITH_OWN_ERRORS


def print_error(command: str, exc: BaseException, as_json: bool) -> None:
    """`exc` as one line on stderr, after the command's name; with `--json` also as
    stdout's last line, `{"error": ...}`, so that a script reading that line gets one."""
    text = error_text(exc)
    print(f"{command}: error: {text}", file=sys.stderr)
    if as_json:
        print(json.dumps({"error": text}))


# OpenCV's list marks, `> Overload resolution failed:`, `>  - src is not ...` (never the
# dashes of an option: `--seconds`)
_BULLET = re.compile(r"^(?:>\s*)?(?:-\s+)?")


def error_text(exc: BaseException) -> str:
    """One line for the user: the message's lines joined (the runtimes put what is wrong
    and where over several: onnxruntime the input, then the sizes), less OpenCV's prefix
    (its version and the C++ file that raised it); a library's error named by its kind."""
    lines = [_BULLET.sub("", line.strip()).rstrip(":") for line in str(exc).splitlines()]
    lines = [line for line in lines if line]
    if lines:
        _, prefix_end, rest = lines[0].partition(" error: ")
        if prefix_end and lines[0].startswith("OpenCV("):
            lines[0] = rest
    text = "; ".join(lines) if lines else "no message"
    if not is_library_error(exc):
        return text
    return f"{type(exc).__module__.split('.')[0]} {type(exc).__name__}: {text}"
