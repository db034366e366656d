"""Parameter plumbing of the node that rcl leaves silent: what the command line asked for, what took.

No ROS here (plain values in, ParameterError out), so every rule is tested without a node.

- `-p name:=value` next to `--params-file` is merged by rcl by type: an override whose type
  differs from the file's (`-p watchdog_timeout:=abc` against `2.0`) is dropped silently and the
  file's value runs. `command_line_overrides` reads the `-p`/`--param` arguments themselves, so
  the node can compare them with what was declared (`override_not_taken`).
- Names nobody declares (a misspelt `-p watchdog_timout:=1`, a key in the params file) are
  refused (`unknown_parameters_message`), with the closest accepted names.
- A key given twice in a params file is refused (`check_params_files`; YAML keeps the last).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pcv_sim.errors import ParameterError
from pcv_sim.params import yaml_load_unique

__all__ = [
    "ROS_OWN_PARAMETERS",
    "Override",
    "check_params_files",
    "command_line_overrides",
    "is_ros_own",
    "numeric_text",
    "override_not_taken",
    "params_files",
    "parse_override_value",
    "refuse_unknown",
    "ros_arguments_message",
    "unknown_parameters_message",
]

#: Parameters rclpy declares itself on every node: never "unknown".
ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service", "qos_overrides.")


def is_ros_own(name: str) -> bool:
    return name.startswith(ROS_OWN_PARAMETERS)


@dataclass(frozen=True)
class Override:
    name: str
    text: str          # as typed, after ':='
    value: Any         # as rcl reads it (YAML scalar or list)

    @property
    def argument(self) -> str:
        return f"-p {self.name}:={self.text}"


def _ros_sections(argv: Sequence[str]) -> Iterable[list[str]]:
    """The argument lists between `--ros-args` and `--` (or the end)."""
    section: list[str] | None = None
    for arg in argv:
        if arg == "--ros-args":
            if section is not None:
                yield section
            section = []
        elif arg == "--" and section is not None:
            yield section
            section = None
        elif section is not None:
            section.append(arg)
    if section is not None:
        yield section


def parse_override_value(text: str) -> Any:
    """A `-p` value as rcl types it: YAML, with numbers YAML 1.1 leaves as text (1e9) read as numbers."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, str):
        for kind in (int, float):
            try:
                return kind(value)
            except ValueError:
                pass
    return text if value is None else value


def command_line_overrides(argv: Sequence[str], node_name: str) -> dict[str, Override]:
    """`-p [node:]name:=value` / `--param ...` arguments that apply to a node named node_name (last wins)."""
    out: dict[str, Override] = {}
    for section in _ros_sections(argv):
        args = iter(section)
        for arg in args:
            if arg in ("-p", "--param"):
                rule = next(args, "")
            elif arg.startswith("--param="):
                rule = arg[len("--param="):]
            else:
                continue
            target, sep, text = rule.partition(":=")
            if not sep:
                continue                                   # rcl refuses it before we run
            node, colon, name = target.rpartition(":")
            if colon and node.lstrip("/").split("/")[-1] not in (node_name, "*", "**"):
                continue
            out[name] = Override(name, text, parse_override_value(text))
    return out


def params_files(argv: Sequence[str]) -> list[str]:
    """The `--params-file FILE` arguments."""
    files = []
    for section in _ros_sections(argv):
        for k, arg in enumerate(section):
            if arg == "--params-file" and k + 1 < len(section):
                files.append(section[k + 1])
    return files


def check_params_files(argv: Sequence[str]) -> None:
    """Refuse a params file that cannot be read, is not YAML, or gives a key twice (ParameterError
    naming the file and the reason, with the line where YAML gives one)."""
    for name in params_files(argv):
        try:
            text = Path(name).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
            raise ParameterError(f"--params-file {name}: cannot read it: {reason}") from None
        try:
            yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ParameterError(f"--params-file {name}: not valid YAML: {_yaml_problem(err)}") from None
        yaml_load_unique(text, f"--params-file {name}")


def _yaml_problem(err: yaml.YAMLError) -> str:
    """One line: what YAML found wrong and where."""
    mark = getattr(err, "problem_mark", None)
    what = " ".join(str(x) for x in (getattr(err, "context", None), getattr(err, "problem", None)) if x) or str(err)
    return f"{what} at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else " ".join(what.split())


def ros_arguments_message(err: Exception) -> str:
    """rcl's refusal of the command line (RCLInvalidROSArgsError) without its C source locations."""
    text = " ".join(str(err).split())
    text = re.sub(r"\s*,? at /\S+:\d+", "", text).strip()
    return text.removeprefix("Failed to parse ROS arguments: ")


_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def numeric_text(value: Any) -> Any:
    """A decimal number given as text ('2e-5') as the float it writes, anything else unchanged.

    `ros2 param set NODE NAME 2e-5` sends a string: YAML 1.1 reads an exponent without a dot as text.
    Only for parameters that take a float: a text parameter keeps its text."""
    if isinstance(value, str) and _DECIMAL.fullmatch(value.strip()):
        return float(value)
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)) or hasattr(b, "tolist"):
        try:
            return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
        except TypeError:
            return False
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return (type(a) is type(b) and a == b) or (
        isinstance(a, (int, float)) and isinstance(b, (int, float))
        and not isinstance(a, bool) and not isinstance(b, bool) and a == b)


def override_not_taken(override: Override, declared: Any) -> bool:
    """True if the node runs with another value than the command line asked for."""
    return not _same(override.value, declared)


def unknown_parameters_message(names: Iterable[str], accepted: Iterable[str], *, hint: str = "") -> str:
    """'unknown parameter(s) a (did you mean b?), c; accepted are ...' for a ParameterError or a reason."""
    accepted = sorted(accepted)
    parts = []
    for name in sorted(names):
        close = difflib.get_close_matches(name, accepted, n=1, cutoff=0.75)
        parts.append(f"{name} (did you mean {close[0]}?)" if close else name)
    return (f"unknown parameter(s) {', '.join(parts)}; accepted are the node's parameters (--help)"
            f"{hint}")


def refuse_unknown(names: Iterable[str], accepted: Iterable[str], *, hint: str = "") -> None:
    names = list(names)
    if names:
        raise ParameterError(unknown_parameters_message(names, accepted, hint=hint))
