"""The lockstep channel: one message per direction per control period between the rig node and a
controller node, instead of one per signal and one per valve.

    out  lockstep/sample   sensor_msgs/JointState   header.stamp = the sample's model time; name = the
                                                    signal names of a lockstep measurement (`<valve>.pressure`
                                                    Pa, `<valve>.current` A, `<valve>.spool_position` m,
                                                    `cylinder.position` m, ...; `setpoint` m in a scenario
                                                    with one); position = the values, SI, NaN: not measured
                                                    (a dropped sample)
    in   lockstep/command  sensor_msgs/JointState   header.stamp = the stamp of the sample it answers;
                                                    name = `<valve>.duty` (fraction 0..1) for the valves it
                                                    commands, `controller.<flag>` for its flags; position =
                                                    the values

A sample is the `measurement` `pcv_sim.rig.run_lockstep` gives a callable, and a command what the
callable returns, under the names `RigRun` gives them: the controller node sees what the callable
sees, in one message, so a period costs two DDS deliveries instead of ~ten (BENCHMARKS.md, "Where a
1 kHz lockstep period goes"). The per-valve and cylinder topics stay what every other client uses.

Both messages are written and read here as CDR bytes (`Publisher.publish(bytes)`, `take_message`
raw): the names do not change within a run, so a sample is a fixed buffer with its stamp and
values packed in, ~1 us instead of ~5 us for rclpy's conversion of a JointState, and reading one is
~3 us instead of ~11 us. The reader takes any JointState in CDR (another language's controller).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from pcv_sim.errors import CommandError
from pcv_sim.io.topics import LOCKSTEP_COMMAND, LOCKSTEP_SAMPLE
from pcv_sim.units import NS_PER_S

__all__ = ["COMMAND_TOPIC", "DUTY_SUFFIX", "FLAG_PREFIX", "SAMPLE_TOPIC", "NamedVector", "decode", "measurement",
           "split_command"]

SAMPLE_TOPIC = LOCKSTEP_SAMPLE
COMMAND_TOPIC = LOCKSTEP_COMMAND
DUTY_SUFFIX = ".duty"
FLAG_PREFIX = "controller."

_ENCAPSULATION = b"\x00\x01\x00\x00"         # CDR, little endian (what Fast DDS writes)
_BODY = len(_ENCAPSULATION)                   # CDR aligns relative to the body's start
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")


def _pad(n: int, to: int) -> int:
    return (-n) % to


class NamedVector:
    """Writes sensor_msgs/JointState CDR for a fixed list of names: `encode(stamp_ns, values)`."""

    def __init__(self, names: Sequence[str], frame_id: str = "") -> None:
        self.names = tuple(names)
        body = bytearray()

        def string(s: str) -> None:
            body.extend(bytes(_pad(len(body), 4)))
            raw = s.encode() + b"\0"
            body.extend(_U32.pack(len(raw)) + raw)

        body.extend(b"\0" * 8)                        # stamp: sec, nanosec
        string(frame_id)
        body.extend(bytes(_pad(len(body), 4)))
        body.extend(_U32.pack(len(self.names)))
        for name in self.names:
            string(name)
        body.extend(bytes(_pad(len(body), 4)))
        body.extend(_U32.pack(len(self.names)))
        if self.names:
            body.extend(bytes(_pad(len(body), 8)))
        self._values_at = _BODY + len(body)
        body.extend(bytes(8 * len(self.names)))
        body.extend(bytes(8))                         # velocity, effort: empty
        self._buf = bytearray(_ENCAPSULATION + body)
        self._values = struct.Struct(f"<{len(self.names)}d")

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        """The message for `values` (one per name, in order) stamped `stamp_ns` (ns, >= 0)."""
        buf = self._buf
        _STAMP.pack_into(buf, _BODY, *divmod(stamp_ns, NS_PER_S))
        self._values.pack_into(buf, self._values_at, *values)
        return bytes(buf)


class _Reader:
    """Reads JointState CDR: (stamp ns, names, positions). The names of the last message are kept:
    a message whose name list has the same bytes is read without decoding them again."""

    def __init__(self) -> None:
        self._blob = b""
        self._names: tuple[str, ...] = ()

    def __call__(self, buf: bytes) -> tuple[int, tuple[str, ...], tuple[float, ...]]:
        if len(buf) < _BODY + 12 or buf[1] != 1:
            raise CommandError(f"lockstep message: not a little-endian CDR sensor_msgs/JointState ({len(buf)} bytes)")
        try:
            sec, nsec = _STAMP.unpack_from(buf, _BODY)
            (n,) = _U32.unpack_from(buf, _BODY + 8)
            at = _BODY + 12 + n
            at += _pad(at - _BODY, 4)
            blob = self._blob
            if blob and buf[at:at + len(blob)] == blob:
                names = self._names
                end = at + len(blob)
            else:
                names, end = _names(buf, at)
                self._blob, self._names = bytes(buf[at:end]), names
            end += _pad(end - _BODY, 4)
            (count,) = _U32.unpack_from(buf, end)
            end += 4
            if count:
                end += _pad(end - _BODY, 8)
            values = struct.unpack_from(f"<{count}d", buf, end)
        except (struct.error, UnicodeDecodeError) as err:
            raise CommandError(f"lockstep message: a malformed sensor_msgs/JointState ({err})") from None
        if count != len(names):
            raise CommandError(f"lockstep message: {len(names)} names and {count} positions; accepted is one "
                               "position per name")
        return sec * NS_PER_S + nsec, names, values


def _names(buf: bytes, at: int) -> tuple[tuple[str, ...], int]:
    (n,) = _U32.unpack_from(buf, at)
    at += 4
    names = []
    for _ in range(n):
        at += _pad(at - _BODY, 4)
        (size,) = _U32.unpack_from(buf, at)
        if size == 0 or at + 4 + size > len(buf):
            raise struct.error("a name runs past the message")
        names.append(bytes(buf[at + 4:at + 3 + size]).decode())
        at += 4 + size
    return tuple(names), at


decode = _Reader()


def split_command(names: Sequence[str], values: Sequence[float], valves: Sequence[str]
                  ) -> tuple[dict[str, float], dict[str, float]]:
    """A command's (duties by valve, flags by name); CommandError naming what is not accepted."""
    duties: dict[str, float] = {}
    flags: dict[str, float] = {}
    for name, value in zip(names, values):
        if name.endswith(DUTY_SUFFIX) and name[:-len(DUTY_SUFFIX)] in valves:
            duties[name[:-len(DUTY_SUFFIX)]] = value
        elif name.startswith(FLAG_PREFIX) and len(name) > len(FLAG_PREFIX):
            flags[name[len(FLAG_PREFIX):]] = value
        else:
            raise CommandError(f"{COMMAND_TOPIC}: {name!r} is not accepted; accepted are "
                               f"{', '.join(v + DUTY_SUFFIX for v in valves)} and {FLAG_PREFIX}<flag>")
    return duties, flags


def measurement(names: Sequence[str], values: Sequence[float]) -> dict[str, float]:
    """A sample as a controller is called with it: NaN (not measured) left out."""
    isnan = math.isnan
    return {n: v for n, v in zip(names, values) if not isnan(v)}
