"""The `follow` command line.

Each command lives in its own module, which provides `add_arguments(parser)` and
`main(args) -> dict | None`. With `--json`, the dict the command returns is printed as
one JSON object on the last line of output.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys

from follow.cli_args import ArgumentParser, is_library_error, print_error

# (command, subcommand or None) -> (module, one-line help); one row per command.
# fmt: off
COMMANDS: dict[tuple[str, str | None], tuple[str, str]] = {
    ("run", None): ("follow.run", "follow a person: camera or video in, base commands out"),
    ("ros2", None): ("follow.ros2.cli", "the ROS 2 node: images and odometry in, target/tracks/cmd_vel out"),
    ("demo", None): ("follow.sim.demo", "the whole stack on a simulated robot (no downloads)"),
    ("eval", "localization"): ("follow.eval.localization", "ground-plane error vs distance (simulation)"),
    ("eval", "pose"): ("follow.eval.pose", "skeleton detector recall/precision on PETS 2009"),
    ("eval", "pose-near"): ("follow.eval.pose_near", "skeleton detector on people seen large (real crops, robot scale)"),
    ("eval", "pose-scene"): ("follow.eval.pose_scene", "people-sized against fixed pose input on a robot's view of real people"),
    ("eval", "crops"): ("follow.eval.crops", "target identification on real person crops"),
    ("eval", "ankle-height"): ("follow.eval.ankle_height", "ankle keypoint height over the annotated ground point (PETS 2009)"),
    ("eval", "walking-accel"): ("follow.eval.walking_accel", "how steadily the annotated people walk: the tracker's acceleration noise (PETS 2009)"),
    ("eval", "tracking"): ("follow.eval.tracking", "CLEAR MOT / IDF1 on PETS 2009 against other trackers"),
    ("eval", "following"): ("follow.eval.following", "closed-loop following over the simulated MAVLink rover"),
    ("eval", "safety"): ("follow.eval.safety", "every fault against the simulated rover: time to standstill, distance driven"),
    ("eval", "identification"): ("follow.eval.identification", "CT/CL/WT/WL on PETS 2009"),
    ("eval", "identification-sim"): ("follow.eval.strangers", "strangers walk in after the target left (simulation)"),
    ("eval", "verification"): ("follow.eval.verification", "open-set target verification on real crops (strangers rejected)"),
    ("bench", None): ("follow.eval.bench", "per-stage latency and end-to-end fps"),
    ("bench", "pose"): ("follow.eval.bench_pose", "pose network runtimes side by side"),
    ("bench", "ros2"): ("follow.ros2.bench", "latency the ROS 2 node adds over perception"),
    ("bench", "memory"): ("follow.eval.bench_memory", "RSS growth over a long synthetic run (bounded memory)"),
    ("bench", "identify"): ("follow.eval.bench_identify", "CCF features and classifier update speed"),
    ("bench", "tracker"): ("follow.eval.bench_tracker", "the tracker alone on PETS detections, per frame and per track"),
    ("models", None): ("follow.models", "list, fetch, verify or prepare the model files"),
}
# fmt: on


def _selected(argv: list[str]) -> tuple[str, str | None] | None:
    """The (command, subcommand) named on the command line, before full parsing."""
    words = [a for a in argv if not a.startswith("-")]
    if not words:
        return None
    if len(words) > 1 and (words[0], words[1]) in COMMANDS:
        return words[0], words[1]
    return (words[0], None) if (words[0], None) in COMMANDS else None


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser; only the module of the command being run is imported."""
    parser = ArgumentParser(prog="follow", description=__doc__.splitlines()[0],
                            json_requested="--json" in argv)  # fmt: skip
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    top = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    chosen = _selected(argv)
    for key, (module_name, help_text) in COMMANDS.items():
        command, sub = key
        if sub is None:
            p = top.add_parser(command, help=help_text, description=help_text)
        else:
            if command not in groups:
                parent = top.choices.get(command) or top.add_parser(
                    command, help=f"{command} commands", description=f"{command} commands"
                )
                groups[command] = parent.add_subparsers(dest="subcommand", metavar="WHAT")
            p = groups[command].add_parser(sub, help=help_text, description=help_text)
        if key == chosen:
            module = importlib.import_module(module_name)
            p.add_argument(
                "--json", action="store_true", help="print one JSON object as the last line"
            )
            module.add_arguments(p)
            p.set_defaults(_module=module, _parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args, extras = parser.parse_known_args(argv)
    trailing = getattr(args, "_names_after_options", None)
    if extras and trailing and not any(word.startswith("-") for word in extras):
        # `follow models fetch --from DIR ccf10`: argparse fills a command's list of names
        # where its first positional stands, and leaves the names after an option over
        getattr(args, trailing).extend(extras)
    elif extras:  # named by the command they were given to, with its usage
        getattr(args, "_parser", parser).error(f"unrecognized arguments: {' '.join(extras)}")
    command_parser = getattr(args, "_parser", parser)
    if empty := _empty_option(command_parser, args):
        command_parser.error(f"argument {empty}: empty; give a value or leave the option out")
    sub = getattr(args, "subcommand", None)
    if sub is not None and _selected(argv) != (args.command, sub):
        # an option's value came before the command's name (`follow bench --frames 5 pose`):
        # the group's own command was set up, and would run in place of the one named
        parser.error(f"give the options of follow {args.command} {sub} after its name: "
                     f"follow {args.command} {sub} [OPTIONS]")  # fmt: skip
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    module = getattr(args, "_module", None)
    if module is None:  # a group (`follow eval`) without one of its commands
        commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        commands.choices[args.command].print_help(sys.stderr)
        print(f"follow {args.command}: error: name one of its commands", file=sys.stderr)
        return 2
    from follow.blas_threads import limit_blas_threads
    from follow.memory import fix_mmap_threshold

    fix_mmap_threshold()  # a robot runs for hours: its memory must not creep
    limit_blas_threads()  # idle BLAS workers must not spin on the network's cores
    try:
        result = module.main(args)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        if not isinstance(exc, ValueError | OSError | RuntimeError) and not is_library_error(exc):
            raise  # a bug of ours: its traceback is what a report needs
        print_error(f"follow {args.command}", exc, getattr(args, "json", False))
        return 1
    if isinstance(result, int):
        return result
    if getattr(args, "json", False) and result is not None:
        print(json.dumps(_strict_json(result), allow_nan=False))
    return 0


def _empty_option(parser: argparse.ArgumentParser, args) -> str | None:
    """The first option given an empty text (`--config ""`): read as no value, it would
    run on the defaults, the current folder or the configuration's own setting."""
    for action in parser._actions:
        value = getattr(args, action.dest, None) if action.option_strings else None
        if isinstance(value, str) and not value.strip():
            return "/".join(action.option_strings)
    return None


def _strict_json(value):
    """`value` with numpy scalars and arrays as Python values and every non-finite
    number (a MOTA with nothing matched, a precision with nothing detected) as None:
    printed as `null`, where `NaN` is no JSON and strict parsers (jq) refuse the line."""
    import math

    import numpy as np

    if isinstance(value, dict):
        return {k: _strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [
            _strict_json(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)
        ]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


if __name__ == "__main__":
    sys.exit(main())
