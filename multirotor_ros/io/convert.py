"""Other logs -> flight-log CSV: format detection and dispatch to one converter per format.

Each converter (:mod:`~multirotor_ros.io.rosbag`, :mod:`~multirotor_ros.io.ulog`,
:mod:`~multirotor_ros.io.dataflash`, :mod:`~multirotor_ros.io.ddd_csv`,
:mod:`~multirotor_ros.io.crazyflie_usd`) documents its topics or
messages, frames and resampling, and writes the same in the log's metadata. Their libraries
(rosbags, pyulog, pymavlink) are imported only when a file of that kind is converted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.io.log_builder import ConversionError
from multirotor_ros.model.airframe import Airframe

FORMATS = ("rosbag2", "ulog", "dataflash", "ddd-csv", "crazyflie-usd")
_ULOG_MAGIC = b"ULog\x01\x12\x35"
_DATAFLASH_MAGIC = b"\xa3\x95\x80"
# Magic 0xBC, then the little-endian u16 format version (1 or 2).
_CRAZYFLIE_USD_STARTS = (b"\xbc\x01\x00", b"\xbc\x02\x00")


@dataclass
class Conversion:
    """A converted log, the format it came from, and what the user should hear about."""

    log: FlightLog
    format: str
    warnings: list[str] = field(default_factory=list)


def detect_format(path: str | Path) -> str:
    """One of :data:`FORMATS`, from the file's content (and, for a directory, its layout)."""
    path = Path(path)
    if path.is_dir() or path.suffix in (".mcap", ".db3"):
        return "rosbag2"
    try:
        with path.open("rb") as stream:
            head = stream.read(4096)
    except OSError as error:
        raise ConversionError(f"{path}: cannot read: {error.strerror or error}") from None
    if head.startswith(_ULOG_MAGIC):
        return "ulog"
    if head.startswith(_DATAFLASH_MAGIC):
        return "dataflash"
    if head.startswith(_CRAZYFLIE_USD_STARTS):
        return "crazyflie-usd"
    from multirotor_ros.io.crazyflie_usd import looks_like_usd_csv
    from multirotor_ros.io.ddd_csv import looks_like_ddd_csv

    first_line = head.split(b"\n", 1)[0].decode("utf-8", errors="replace")
    header = [cell.strip() for cell in first_line.split(",")]
    if looks_like_ddd_csv(header):
        return "ddd-csv"
    if looks_like_usd_csv(header):
        return "crazyflie-usd"
    if head.startswith(b"#") or first_line.startswith("t,"):
        raise ConversionError(
            f"{path}: already a flight log (metadata or a 't,...' header): nothing to convert"
        )
    raise ConversionError(
        f"{path}: unknown format (not a rosbag2 directory, ULog, dataflash .bin, "
        "data-driven-dynamics CSV or Crazyflie usd log, binary or CSV); give --format"
    )


def convert(
    path: str | Path,
    airframe: Airframe,
    fmt: str = "auto",
    namespace: str | None = None,
    rotor_channels: str | None = None,
    actuator_instance: int | None = None,
) -> Conversion:
    """Convert ``path`` to a :class:`FlightLog` for ``airframe``.

    ``namespace`` applies to rosbag2 only; ``rotor_channels`` (``"1,4,2,3"``: channel of rotor 1, 2,
    ...) to the formats with actuator outputs; ``actuator_instance`` (default 0) to ULog only.
    """
    path = Path(path)
    if not path.exists():
        raise ConversionError(f"{path}: no such file or directory")
    kind = detect_format(path) if fmt == "auto" else fmt
    if kind not in FORMATS:
        raise ConversionError(f"unknown format {fmt!r}; choose auto or one of {', '.join(FORMATS)}")
    if kind == "rosbag2":
        if rotor_channels is not None:
            raise ConversionError("--rotor-channels does not apply to rosbag2: motor_speeds names its rotors")
        from multirotor_ros.io.rosbag import convert_rosbag2

        log, warnings = convert_rosbag2(path, airframe, namespace)
    else:
        if namespace is not None:
            raise ConversionError(f"--namespace applies to rosbag2 only, not {kind}")
        if actuator_instance is not None and kind != "ulog":
            raise ConversionError(f"--actuator-instance applies to ULog only, not {kind}")
        if kind == "ulog":
            from multirotor_ros.io.ulog import convert_ulog

            log, warnings = convert_ulog(path, airframe, rotor_channels, actuator_instance or 0)
        elif kind == "dataflash":
            from multirotor_ros.io.dataflash import convert_dataflash

            log, warnings = convert_dataflash(path, airframe, rotor_channels)
        elif kind == "crazyflie-usd":
            from multirotor_ros.io.crazyflie_usd import convert_crazyflie_usd

            log, warnings = convert_crazyflie_usd(path, airframe, rotor_channels)
        else:
            from multirotor_ros.io.ddd_csv import convert_ddd_csv

            log, warnings = convert_ddd_csv(path, airframe, rotor_channels)
    log.validate(airframe.n_rotors)
    return Conversion(log, kind, warnings)
