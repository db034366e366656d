"""rosbag2's ``metadata.yaml`` (version 9), offered QoS profiles and the ROS distribution.

rosbag2 (``ros2 bag``) and rosbags read the bag's topics, counts and files from
``metadata.yaml``; ``ros2 bag play`` republishes each topic with the QoS recorded in its
``offered_qos_profiles`` (without one it offers reliable, depth 10, which a best-effort
subscriber still accepts but a sensor-data topic was not). Version 9 writes the profiles as a
YAML sequence with policy names (``keep_last``, ``best_effort``); the MCAP channel metadata holds
the same sequence as one YAML string (what rosbag2's MCAP storage plugin writes). Durations are
rmw's "infinite" (9223372036 s 854775807 ns) and liveliness ``automatic``: what rosbag2 records
from a publisher that left them at their defaults (see docs/interface.md).
"""

from __future__ import annotations

import importlib.metadata
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

import yaml

from pcv_sim.errors import BagError

__all__ = [
    "COMMAND_QOS",
    "METADATA_VERSION",
    "SENSOR_DATA_QOS",
    "FileStats",
    "Qos",
    "TopicRecord",
    "check_ros_distro",
    "detect_ros_distro",
    "dump_yaml",
    "load_metadata",
    "metadata_document",
    "qos_yaml",
]

METADATA_VERSION: Final = 9
U64_END: Final = 1 << 64
_INFINITE: Final = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE
#: rclpy major version -> distribution, for the PyPI wheels (no ROS_DISTRO set): Jazzy ships
#: rclpy 7.x, Kilted 9.x (measured: docs/ros_wheels.md).
_RCLPY_DISTRO: Final = {7: "jazzy", 9: "kilted"}
_DISTRO_OK: Final = re.compile(r"^[a-z][a-z0-9_]*$|^$")


@dataclass(frozen=True)
class Qos:
    """The policies of an offered QoS profile that matter for playback (rosbag2's names)."""

    reliability: Literal["reliable", "best_effort"]
    depth: int
    history: Literal["keep_last", "keep_all"] = "keep_last"
    durability: Literal["volatile", "transient_local"] = "volatile"

    def __post_init__(self) -> None:
        if self.reliability not in ("reliable", "best_effort"):
            msg = f"QoS reliability {self.reliability!r}: accepted are 'reliable', 'best_effort'"
            raise BagError(msg)
        if self.history not in ("keep_last", "keep_all"):
            msg = f"QoS history {self.history!r}: accepted are 'keep_last', 'keep_all'"
            raise BagError(msg)
        if self.durability not in ("volatile", "transient_local"):
            msg = f"QoS durability {self.durability!r}: accepted are 'volatile', 'transient_local'"
            raise BagError(msg)
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            msg = f"QoS depth {self.depth!r}: accepted is an integer >= 0"
            raise BagError(msg)

    def as_dict(self) -> dict[str, Any]:
        """The profile as rosbag2 writes it in metadata version 9, keys in its order."""
        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": dict(_INFINITE),
            "lifespan": dict(_INFINITE),
            "liveliness": "automatic",
            "liveliness_lease_duration": dict(_INFINITE),
            "avoid_ros_namespace_conventions": False,
        }


#: rclpy's ``qos_profile_sensor_data``: the emulator's outputs.
SENSOR_DATA_QOS: Final = Qos("best_effort", 5)
#: ``QoSProfile(depth=10)``: the emulator's command inputs.
COMMAND_QOS: Final = Qos("reliable", 10)


def qos_yaml(profiles: Sequence[Qos]) -> str:
    """The ``offered_qos_profiles`` string of MCAP channel metadata (``[]`` for none, as
    rosbag2 dumps an empty sequence)."""
    if not profiles:
        return "[]"
    return dump_yaml([q.as_dict() for q in profiles]).strip()


def detect_ros_distro() -> str:
    """The ROS 2 distribution in use, without importing rclpy: ``ROS_DISTRO`` when set (a
    sourced ROS install sets it), else the installed rclpy wheel's major version; "" if unknown
    (rosbag2 also writes "" when ``ROS_DISTRO`` is unset)."""
    env = os.environ.get("ROS_DISTRO", "").strip()
    if env:
        return env
    # The Kilted wheels install the distributions rclpy and ros-rclpy, the Jazzy ones
    # ros-jazzy-rclpy (requirements/*.txt): a distribution name that says it wins.
    for name in ("ros-jazzy-rclpy", "ros-kilted-rclpy", "ros-rolling-rclpy", "rclpy", "ros-rclpy"):
        try:
            version = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
        if name.count("-") == 2:
            return name.split("-")[1]
        try:
            return _RCLPY_DISTRO.get(int(version.split(".")[0]), "")
        except ValueError:
            return ""
    return ""


def check_ros_distro(distro: object) -> str:
    if not isinstance(distro, str) or not _DISTRO_OK.match(distro):
        msg = f"ros_distro {distro!r}: accepted is a lower-case distribution name like 'kilted', or ''"
        raise BagError(msg)
    return distro


@dataclass
class TopicRecord:
    """Writer-side state of one topic; its MCAP channel id is the same in every split file."""

    name: str
    msgtype: str
    channel_id: int
    type_hash: str
    qos: tuple[Qos, ...] = ()
    count: int = 0


@dataclass
class FileStats:
    """Per MCAP file numbers for ``metadata.yaml``'s ``files`` list."""

    name: str
    count: int = 0
    t_min: int = U64_END
    t_max: int = 0

    def as_yaml(self) -> dict[str, Any]:
        start = self.t_min if self.count else 0
        return {
            "path": self.name,
            "starting_time": {"nanoseconds_since_epoch": start},
            "duration": {"nanoseconds": self.t_max - start if self.count else 0},
            "message_count": self.count,
        }


def metadata_document(
    topics: Iterable[TopicRecord], files: Sequence[FileStats], ros_distro: str
) -> dict[str, Any]:
    """``metadata.yaml`` content as rosbags' and rosbag2's writers make it (version 9)."""
    topics = list(topics)
    counted = [f for f in files if f.count]
    count = sum(f.count for f in files)
    t_min = min((f.t_min for f in counted), default=U64_END)
    t_max = max((f.t_max for f in counted), default=0)
    start = t_min if count else 0
    return {
        "rosbag2_bagfile_information": {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": t_max - start if count else 0},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [q.as_dict() for q in t.qos],
                        "type_description_hash": t.type_hash,
                    },
                    "message_count": t.count,
                }
                for t in topics
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [f.name for f in files],
            "files": [f.as_yaml() for f in files],
            "custom_data": None,
            "ros_distro": ros_distro,
        }
    }


def dump_yaml(data: object) -> str:
    """Block-style YAML in rosbag2's key order; wide lines keep RIHS01 hashes on one line."""
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False, width=4096)


def load_metadata(path: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of a bag directory, checked for what
    :func:`pcv_sim.io.bag.read_bag` can read (MCAP storage, no file-level compression)."""
    meta_path = path / "metadata.yaml"
    try:
        doc = yaml.safe_load(meta_path.read_text("utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"cannot read {str(meta_path)!r}: {exc}"
        raise BagError(msg) from exc
    except yaml.YAMLError as exc:
        msg = f"{str(meta_path)!r} is not valid YAML: {exc}"
        raise BagError(msg) from exc
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        msg = f"{str(meta_path)!r} has no 'rosbag2_bagfile_information' mapping; not a rosbag2 bag"
        raise BagError(msg)
    storage = info.get("storage_identifier", "")
    if storage != "mcap":
        msg = f"{str(path)!r} uses storage {storage!r}; only 'mcap' bags can be read"
        raise BagError(msg)
    mode = str(info.get("compression_mode") or "").lower()
    if mode not in ("", "none"):
        msg = (
            f"{str(path)!r} uses rosbag2 {mode!r} compression; only uncompressed bags "
            f"(MCAP chunk compression is fine) can be read"
        )
        raise BagError(msg)
    return info
