"""What every `obsbench` command shares: argparse value types, one parser per command, one-line errors.

A command module (`lerobot_obsbench.commands.<name>`, LeRobot's `scripts/lerobot_<name>.py` in small) holds:
`NAME`, `HELP` (one line for `obsbench --help`), `EXAMPLE` (shown by `--help`, and parsed by the tests),
`INTERRUPTED` (what a Ctrl-C keeps), `add_arguments(parser)`, `run(args) -> exit code` and its own `main`, so
`python -m lerobot_obsbench.commands.<name>` and `obsbench <name>` are the same command.

Commands that drive LeRobot devices also set `DEVICE_OPTIONS` (e.g. `("robot", "teleop")`): their
`--robot.*` / `--teleop.*` options are handed to LeRobot's own draccus configs, exactly as `lerobot-record` takes
them, while the command's own options stay argparse ones.
"""

from __future__ import annotations

import argparse
import math
import sys
from types import ModuleType

from lerobot_obsbench.errors import ObsBenchError, UsageError
from lerobot_obsbench.numeric import number_argument
from lerobot_obsbench.schema import MIN_IMAGE_SIZE

# What a Ctrl-C keeps, for a command that does not say.
NOTHING_HALF_WRITTEN = "nothing is left half-written; run the same command again"


positive_int = number_argument(whole=True, minimum=1)  # counts, sizes, rates
non_negative_int = number_argument(whole=True, minimum=0)  # indices
positive_float = number_argument(above=0)  # a size, a distance, an angle
non_negative_float = number_argument(minimum=0)  # a wait
fraction = number_argument(above=0, maximum=1)  # a share


def device_name(text: str) -> str:
    """argparse type: the name of a torch device (cpu, cuda, cuda:N, mps), for devices of other machines."""
    import torch

    try:
        device = torch.device(text)
    except RuntimeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a torch device; give cpu, cuda, cuda:N or mps") from None
    if device.type not in ("cpu", "cuda", "mps"):
        raise argparse.ArgumentTypeError(f"{text}: give cpu, cuda, cuda:N or mps")
    return text


def torch_device(text: str) -> str:
    """argparse type: a torch device this machine has, checked before a policy or a simulator loads."""
    import torch

    device = torch.device(device_name(text))
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise argparse.ArgumentTypeError(f"{text}: this machine has no CUDA GPU torch can use; give cpu")
        if device.index is not None and device.index >= count:
            raise argparse.ArgumentTypeError(f"{text}: this machine has {count} CUDA GPU(s), cuda:0..cuda:{count - 1}")
    elif device.type == "mps" and not torch.backends.mps.is_available():
        raise argparse.ArgumentTypeError(f"{text}: Apple's MPS is not available here; give cpu")
    return text


def crop_box_argument(workspace: list[float] | None, flag: str = "--workspace") -> None:
    """Refuse an inverted, empty or non-finite crop box given on the command line."""
    if workspace is None:
        return
    lows, highs = workspace[0::2], workspace[1::2]
    if not all(math.isfinite(v) for v in workspace) or any(lo >= hi for lo, hi in zip(lows, highs, strict=True)):
        raise UsageError(
            f"{flag} {' '.join(f'{v:g}' for v in workspace)}: give xmin xmax ymin ymax zmin zmax in metres, each "
            "min below its max"
        )


def frame_size(text: str) -> int:
    """argparse type: a camera frame size in pixels, at least the smallest every stage handles."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of pixels, got {text!r}") from None
    if value < MIN_IMAGE_SIZE:
        raise argparse.ArgumentTypeError(
            f"must be >= {MIN_IMAGE_SIZE} pixels (LeRobot's video encoder fails on smaller frames), got {value}"
        )
    return value


def configure(parser: argparse.ArgumentParser, command: ModuleType) -> argparse.ArgumentParser:
    """Give `parser` the command's options, its example and its handler."""
    parser.epilog = "example:\n  " + command.EXAMPLE.replace("\n", "\n  ")
    if getattr(command, "DEVICE_OPTIONS", ()):
        groups = ", ".join(f"--{group}.*" for group in command.DEVICE_OPTIONS)
        parser.epilog += (
            f"\n\n{groups}: LeRobot's own configs, as lerobot-record takes them (--robot.type=... then that "
            "type's fields, e.g. --robot.port=/dev/ttyACM0 --robot.id=follower)"
        )
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    command.add_arguments(parser)
    parser.set_defaults(command=command)
    return parser


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """argparse, except that a device command keeps its `--robot.*` / `--teleop.*` options for LeRobot's parser."""
    args, rest = parser.parse_known_args(argv)
    groups = getattr(getattr(args, "command", None), "DEVICE_OPTIONS", ())
    device_options, unknown = [], []
    for item in rest:
        if any(item.startswith(f"--{group}.") for group in groups):
            device_options.append(item)
        elif device_options and "=" not in device_options[-1] and not item.startswith("-"):
            device_options[-1] += f"={item}"  # `--robot.port /dev/ttyACM0`, spelled with a space
        else:
            unknown.append(item)
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    args.device_options = device_options
    return args


def run(command: ModuleType, args: argparse.Namespace) -> int:
    """Run a parsed command: an error raised on purpose, a bad path, a refusing Hub or a Ctrl-C is one line."""
    import httpx
    from huggingface_hub.errors import HfHubHTTPError, OfflineModeIsEnabled

    import lerobot_obsbench  # noqa: F401  (registers the policies, encoders, envs, robots and cameras)

    # a device command also expects ValueError: LeRobot's device factories wrap a missing SDK or a bad port in one
    own = getattr(command, "EXPECTED_ERRORS", ())
    expected = (ObsBenchError, PermissionError, FileNotFoundError, FileExistsError, *own)
    try:
        return command.run(args)
    except expected as err:  # raised on purpose (its message names the field and the fix), or a path given
        print(f"obsbench {command.NAME}: error: {err}", file=sys.stderr)
        return 2
    except (HfHubHTTPError, OfflineModeIsEnabled, httpx.HTTPError) as err:  # the Hub refused, or is unreachable
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        print(
            f"obsbench {command.NAME}: error: the Hugging Face Hub: {first} (check the network, HF_HUB_OFFLINE and "
            "your token: hf auth login)",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:  # what was kept, and the shell's exit code for a SIGINT
        kept = getattr(command, "INTERRUPTED", NOTHING_HALF_WRITTEN)
        print(f"\nobsbench {command.NAME}: interrupted; {kept}", file=sys.stderr)
        return 130


def main(command: ModuleType, argv: list[str] | None = None) -> int:
    """A command module's own entry point: `python -m lerobot_obsbench.commands.<name> ...`."""
    parser = configure(argparse.ArgumentParser(prog=f"obsbench {command.NAME}", description=command.HELP), command)
    return run(command, parse(parser, sys.argv[1:] if argv is None else list(argv)))


def device_configs(config_class: type, options: list[str], command: str):
    """`--robot.*` / `--teleop.*` options -> LeRobot's configs (its draccus choice registry), one-line errors."""
    import draccus
    from draccus.utils import DraccusException

    try:
        return draccus.parse(config_class, args=options)
    except DraccusException as err:
        raise UsageError(f"{err} (see `obsbench {command} --help`)") from None
    except SystemExit:  # draccus prints what is wrong (a missing or unknown field, a bad value) and exits
        raise UsageError(f"invalid --robot.* / --teleop.* options (see above; `obsbench {command} --help`)") from None


def keyboard_events() -> dict:
    """LeRobot's keyboard controls for the device commands (right arrow, left arrow, Escape), as its dict of
    events."""
    from lerobot.utils.keyboard_input import init_keyboard_listener

    return init_keyboard_listener()[1]


def _dest(prefix: str, name: str) -> str:
    """Where argparse keeps config field `name` of the `--<prefix>.*` options."""
    return f"{prefix}_{name}" if prefix else name


def true_or_false(text: str) -> bool:
    """argparse type of a boolean config field, LeRobot's spelling: `--field=true|false`."""
    value = text.strip().lower()
    if value not in ("true", "false", "1", "0", "yes", "no"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return value in ("true", "1", "yes")


def add_config_options(parser: argparse.ArgumentParser, config_class: type, prefix: str = "") -> None:
    """One `--<prefix>.<field>` option per field of a dataclass config (`--<field>` without a prefix), typed from
    its annotation and documented by the comment above the field, as draccus documents LeRobot's configs."""
    import dataclasses
    import types
    import typing

    from draccus.wrappers.docstring import get_attribute_docstring, get_preferred_help_text

    hints = typing.get_type_hints(config_class)
    for field in dataclasses.fields(config_class):
        kind = hints[field.name]
        if isinstance(kind, types.UnionType):  # `X | None`: a value of type X, or the None default
            kind = next(k for k in typing.get_args(kind) if k is not type(None))
        comment = get_preferred_help_text(get_attribute_docstring(config_class, field.name)) or ""
        help_text = comment.replace("%", "%%")  # argparse %-formats help texts
        required = field.default is dataclasses.MISSING
        default = None if required else field.default
        option = {"type": kind, "metavar": kind.__name__.upper()}
        if kind is bool:  # `--field` alone means true
            option = {"type": true_or_false, "nargs": "?", "const": True, "metavar": "true|false"}
        parser.add_argument(
            f"--{prefix}.{field.name}" if prefix else f"--{field.name}",
            dest=_dest(prefix, field.name),
            required=required,
            default=default,
            help=f"{help_text} (default: {str(default).replace('%', '%%')})".strip() if not required else help_text,
            **option,
        )


def config_from_args(config_class: type, args: argparse.Namespace, prefix: str = ""):
    """The dataclass config `add_config_options` made options for, from the parsed arguments."""
    import dataclasses

    return config_class(**{f.name: getattr(args, _dest(prefix, f.name)) for f in dataclasses.fields(config_class)})
