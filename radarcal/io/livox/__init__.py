"""Livox LiDARs: SDK 1 (Mid-40/70, Horizon, Avia, Tele) and SDK 2 (HAP, Mid-360) control and point packets
(:mod:`sdk1`, :mod:`sdk2`), a live source that starts the sensor itself and a packet decoder shared with replays
(:mod:`source`)."""

from radarcal.io.livox.source import (
    LivoxHealth,
    LivoxSource,
    PacketDecoder,
    parse_livox_url,
)

__all__ = ["LivoxHealth", "LivoxSource", "PacketDecoder", "open_livox", "parse_livox_url"]


def open_livox(spec: str, sensor: str = "", packet_tap=None, **overrides) -> LivoxSource:
    """A started :class:`LivoxSource` for ``livox://IP``, ``livox1://IP``, ``livox2://IP`` or ``livox://HOST:PORT``."""
    o = parse_livox_url(spec)
    src = LivoxSource(o["ip"], sdk=o["sdk"], host=o.get("host"), sensor=o.get("name", sensor), frame_s=o.get("frame", 0.1), timeout_s=o.get("timeout", 2.0),
                      discovery_port=o.get("discovery_port"), cmd_port=o.get("cmd_port"), data_type=o.get("data_type"), listen_port=o["listen_port"],
                      packet_tap=packet_tap, **overrides)  # fmt: skip
    return src.start()
