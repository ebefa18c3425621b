"""The `follow-calib` command line: produce and check the camera file `follow` reads.

Each command lives in its own module, which provides `add_arguments(parser)` and
`main(args) -> dict | None`. With `--json`, the dict the command returns is printed as
one JSON object on the last line of output. Errors in the input (a malformed file, no
chessboard found) end the command with a one-line message and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import math
import sys

from follow.cli_args import ArgumentParser, is_library_error, print_error

# command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "intrinsics": ("calib.intrinsics_cmd", "camera matrix and distortion from chessboard views"),
    "ground": ("calib.ground_cmd", "camera height, pitch and roll from a chessboard on the floor"),
    "import-tsai": ("calib.tsai_cmd", "convert a Tsai calibration (PETS 2009 XML)"),
    "check": ("calib.check_cmd", "draw a camera file's ground grid over a frame"),
}


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser; only the module of the command being run is imported."""
    parser = ArgumentParser(prog="follow-calib", description=__doc__.splitlines()[0],
                            json_requested="--json" in argv)  # fmt: skip
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            module = importlib.import_module(module_name)
            p.add_argument(
                "--json", action="store_true", help="print one JSON object as the last line"
            )
            module.add_arguments(p)
            p.set_defaults(_module=module)
    return parser


def _jsonable(value):
    """Plain JSON: NaN/inf become null, numpy scalars become Python numbers."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return _jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        result = args._module.main(args)
    except Exception as exc:
        if not isinstance(exc, ValueError | OSError) and not is_library_error(exc):
            raise  # a bug of ours: its traceback is what a report needs
        print_error(f"follow-calib {args.command}", exc, getattr(args, "json", False))
        return 2
    if getattr(args, "json", False) and result is not None:
        print(json.dumps(_jsonable(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
