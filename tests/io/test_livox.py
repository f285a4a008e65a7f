"""Livox SDK 1 / SDK 2: checksums, control frames, packet decoding against known points, and the live source
against the loopback simulator (discovery -> handshake -> streaming, outages, bad packets)."""

from __future__ import annotations

import itertools
import socket
import struct
import time

import numpy as np
import pytest

from radarcal.io.livox import LivoxSource, PacketDecoder, parse_livox_url, sdk1, sdk2
from radarcal.io.livox.crc import crc16_ccitt_false, crc16_mcrf4xx, crc32
from radarcal.synth.livox_sim import LivoxSimulator

_ips = itertools.count(20)


def _free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


def _pair(model: str, **sim_kw):
    """A simulator on its own loopback address and a LivoxSource that finds it (SDK chosen automatically)."""
    ip = f"127.0.{np.random.default_rng().integers(1, 250)}.{next(_ips)}"
    disc = _free_port() if model.startswith("mid7") else None
    sim = LivoxSimulator(model, ip=ip, host="127.0.0.1", discovery_port=disc, **sim_kw).start()
    src = LivoxSource(ip, host="127.0.0.1", sensor="lidar0", discovery_port=disc, timeout_s=1.5).start()  # heartbeat every 0.8 s: 0.7 s slack on a loaded machine
    return sim, src


def _wait(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def test_checksums_match_the_catalogued_check_values():
    assert crc16_mcrf4xx(b"123456789", 0xFFFF) == 0x6F91  # CRC-16/MCRF4XX
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE
    assert crc32(b"123456789") == 0xCBF43926


def test_control_frames_round_trip_and_corruption_is_rejected():
    f = sdk1.pack_frame(sdk1.CMD, 7, 0, sdk1.HANDSHAKE, socket.inet_aton("127.0.0.1") + struct.pack("<HHH", 1, 2, 3))
    assert len(f) == 15 + 10 and f[0] == 0xAA and f[1] == 1 and struct.unpack_from("<H", f, 2)[0] == len(f)
    g = sdk1.parse_frame(f)
    assert (g.cmd_type, g.seq, g.cmd_set, g.cmd_id, g.payload[4:]) == (0, 7, 0, 1, struct.pack("<HHH", 1, 2, 3))
    for i in (3, 9, 12, len(f) - 1):  # preamble, CRC16, payload, CRC32
        bad = bytearray(f)
        bad[i] ^= 0x40
        assert sdk1.parse_frame(bytes(bad)) is None
    h = sdk2.pack_frame(sdk2.REQ, 70000, sdk2.SET_PARAMS, sdk2.pack_params([(sdk2.KEY_WORK_MODE, b"\x01"), (sdk2.KEY_DATA_TYPE, b"\x02")]))
    k = sdk2.parse_frame(h)
    assert k.seq == 70000 and k.cmd_id == 0x0100 and sdk2.parse_params(k.payload) == {0x001A: b"\x01", 0x0000: b"\x02"}
    assert sdk2.parse_frame(h[:-1]) is None and sdk2.parse_frame(h[:20] + bytes([h[20] ^ 1]) + h[21:]) is None
    assert sdk2.parse_frame(sdk2.pack_frame(sdk2.REQ, 1, sdk2.DISCOVERY)).payload == b""


def _truth(n, seed=0):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-30, 30, (n, 3)).round(3)
    xyz[::17] = 0  # no return
    return xyz, rng.integers(1, 255, n).astype(float)


@pytest.mark.parametrize("sdk,data_type", [(1, 0), (1, 2), (2, 1), (2, 2)])
def test_decoder_recovers_the_encoded_points_and_cuts_clouds_by_sensor_time(sdk, data_type):
    n_pkt = 40
    npp = 100 if (sdk, data_type) == (1, 0) else 96
    xyz, refl = _truth(n_pkt * npp)
    if sdk == 1:
        pk = sdk1.encode_packets(xyz, refl, 10**9, data_type)
        step = npp * 10_000
    else:
        pk = sdk2.encode_packets(xyz, refl, 10**9, point_interval_ns=10_000, data_type=data_type)
        step = npp * 10_000
        xyz = np.round(xyz * 100) / 100 if data_type == 2 else xyz
    dec = PacketDecoder(sdk, frame_s=0.01, sensor="l")  # 10 ms clouds; packets ~1 ms apart
    for i, p in enumerate(pk):
        dec.feed(p.tobytes(), 0.5 + i * 1e-3)
    clouds = dec.finish()
    got = np.concatenate([c.points for c in clouds])
    want = xyz[np.any(xyz != 0, axis=1)]
    np.testing.assert_allclose(got, want, atol=6e-7 * 30)
    assert dec.health.packets == n_pkt and dec.health.points == len(want) and dec.health.drops == 0
    per_cloud = 10**7 // step + (10**7 % step > 0)
    assert len(clouds) == int(np.ceil(n_pkt / (10**7 / step))) and all(c.sensor == "l" for c in clouds)
    assert clouds[0].t == pytest.approx(0.5 + (per_cloud - 1) * 1e-3)


def test_spherical_and_dual_return_packets():
    pk = np.zeros(1, sdk1.packet_dtype(1))
    pk["data_type"] = 1
    pk["pts"]["depth"][0, :2] = 10000
    pk["pts"]["theta"][0, :2] = 9000
    pk["pts"]["phi"][0, :2] = (3000, 9000)  # 30 deg and 90 deg azimuth, horizontal
    xyz, _, keep = sdk1.decode_points(pk, 1)
    np.testing.assert_allclose(xyz, [[10 * np.cos(np.radians(30)), 5.0, 0.0], [0, 10, 0]], atol=1e-5)
    assert keep.sum() == 2
    d = np.zeros(1, sdk1.packet_dtype(5))
    d["pts"]["depth"][0, 0], d["pts"]["depth2"][0, 0], d["pts"]["theta"][0, 0] = 5000, 8000, 0  # straight up: z
    xyz, _, _ = sdk1.decode_points(d, 5)
    np.testing.assert_allclose(xyz, [[0, 0, 5], [0, 0, 8]], atol=1e-6)
    s = np.zeros(1, sdk2.packet_dtype(3, 96))
    s["pts"]["depth"][0, 0], s["pts"]["theta"][0, 0], s["pts"]["phi"][0, 0] = 2000, 9000, 18000
    xyz, _, _ = sdk2.decode_points(s, 3)
    np.testing.assert_allclose(xyz, [[-2, 0, 0]], atol=1e-5)


def test_decoder_counts_bad_truncated_dropped_and_imu_packets_without_crashing():
    xyz, refl = _truth(96 * 10, 1)
    pk = sdk2.encode_packets(xyz, refl, 10**9, udp_cnt0=65530)  # the udp counter wraps
    dec = PacketDecoder(2)
    raw = [p.tobytes() for p in pk]
    feed = raw[:3] + [raw[3][:50], b"", b"\xaa" * 7, raw[4][:10] + bytes([0x33]) + raw[4][11:]] + raw[5:] + [raw[0] + b"x"]
    imu = bytearray(raw[0][:36] + bytes(24))
    imu[10] = 0
    feed.append(bytes(imu))
    for i, b in enumerate(feed):
        dec.feed(b, i * 1e-3)
    dec.finish()
    h = dec.health
    assert (h.packets, h.truncated_packets, h.bad_packets, h.imu_packets) == (8, 3, 2, 1)
    assert h.drops == 2  # packets 3 and 4 never arrived intact (udp counter 65533 -> 65535)
    assert h.points == np.any(xyz[: 3 * 96] != 0, 1).sum() + np.any(xyz[5 * 96 :] != 0, 1).sum()
    rng = np.random.default_rng(0)
    noise = PacketDecoder(1)
    for _ in range(300):  # random datagrams: counted, never a crash
        noise.feed(rng.bytes(int(rng.integers(0, 1500))), 0.0)
    noise.finish()
    n = noise.health
    assert n.packets == 0 and n.bad_packets + n.truncated_packets + n.imu_packets == 300


def test_listen_only_url_decodes_packets_sent_by_another_tool():
    port = _free_port()
    src = LivoxSource("127.0.0.1", listen_port=port).start()
    try:
        xyz, refl = _truth(96 * 25, 3)
        pk = sdk1.encode_packets(xyz, refl, 0, 2)
        pk["timestamp"] = np.arange(25, dtype=np.uint64) * 10_000_000  # 10 ms apart -> 2 complete 100 ms clouds
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for p in pk:
            tx.sendto(p.tobytes(), ("127.0.0.1", port))
        got = []
        assert _wait(lambda: got.extend(src.poll()) or len(got) >= 2, 3.0)
        assert [len(c.points) for c in got[:2]] == [np.any(xyz[k * 960 : (k + 1) * 960] != 0, 1).sum() for k in range(2)]
        assert src.health.packets == 25 and src.health.sdk == 1
    finally:
        src.close()
    assert parse_livox_url("livox://0.0.0.0:56001")["listen_port"] == 56001
    o = parse_livox_url("livox2://192.168.1.12?host=192.168.1.5&name=hap")
    assert (o["sdk"], o["ip"], o["host"], o["name"], o["listen_port"]) == (2, "192.168.1.12", "192.168.1.5", "hap", None)


def _stream_exact(model: str, n_packets: int, timeout: float):
    sim, src = _pair(model, max_packets=n_packets)
    try:
        n_cloud_points = [0]

        def drained():
            n_cloud_points[0] += sum(len(c) for c in src.poll())
            return sim.done() and src.health.packets + src.health.drops >= sim.packets_sent

        assert _wait(drained, timeout), (src.health.snapshot(), sim.packets_sent)  # the in-process simulator may lag under load: it waits
        h = src.health
        assert h.state == "streaming" and h.sdk == sim.sdk and sim.handshakes >= 1
        assert h.packets == sim.packets_sent == n_packets and h.drops == 0 and h.bad_packets == 0
        assert h.points == sim.points_sent and h.raw_points == sim.slots_sent
        assert n_cloud_points[0] <= h.points and h.clouds >= 1
        return h
    finally:
        src.close()
        sim.close()


@pytest.mark.parametrize("model,n", [("mid70", 2500), ("hap", 9000)])
def test_simulator_discovery_handshake_streaming_without_loss(model, n):
    h = _stream_exact(model, n, 15.0)
    assert h.device == {"mid70": "Mid-70", "hap": "HAP"}[model]


@pytest.mark.slow
@pytest.mark.parametrize("model", ["mid70", "hap"])
def test_simulator_60s_stream_without_loss(model):
    """60 s at the sensor's rate, the simulator in its own process (`radarcal synth livox-sim --packets N`)."""
    import re
    import subprocess
    import sys

    rate = {"mid70": 100_000, "hap": 452_000}[model]
    n = int(60 * rate / 96)
    ip = f"127.0.{np.random.default_rng().integers(1, 250)}.{next(_ips)}"
    disc = _free_port() if model == "mid70" else None
    cmd = [sys.executable, "-m", "radarcal", "synth", "livox-sim", "--model", model, "--ip", ip, "--packets", str(n)] + (["--discovery-port", str(disc)] if disc else [])
    src = LivoxSource(ip, host="127.0.0.1", sensor="lidar0", discovery_port=disc).start()
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        points = 0
        while proc.poll() is None and time.monotonic() - t0 < 400:
            points += sum(len(c) for c in src.poll())
            time.sleep(0.05)
        out = proc.communicate(timeout=10)[0]
        time.sleep(0.5)
        points += sum(len(c) for c in src.poll())
    finally:
        src.close()
    sent, slots, pts = (int(v) for v in re.search(r"sent (\d+) packets \((\d+) point slots\), (\d+) points", out).groups())
    h = src.health
    wall = time.monotonic() - t0
    print(f"{model}: {sent} packets / {pts} points sent in {wall:.0f} s; received {h.packets} packets, {h.points} points, drops {h.drops}")
    assert sent == n and h.packets == sent and h.points == pts and h.raw_points == slots and h.drops == 0 and h.reconnects == 0
    assert points <= h.points


@pytest.mark.parametrize("model", ["mid70", "mid360"])
def test_heartbeat_outage_reconnects_and_bad_packets_are_counted(model):
    sim, src = _pair(model)
    try:
        assert _wait(lambda: src.health.packets > 300, 5.0)
        sim.inject("malformed", 3)
        sim.inject("truncated", 4)
        assert _wait(lambda: sim.bad_sent == 3 and sim.truncated_sent == 4, 3.0)
        sim.outage(2.0)
        p0 = src.health.packets
        assert _wait(lambda: src.health.reconnects >= 1 and src.health.packets > p0 + 200, 8.0), src.health.snapshot()
        assert sim.handshakes >= 2 and src.health.state == "streaming"
        src.poll()
        h = src.health
        assert (h.bad_packets, h.truncated_packets, h.drops) == (3, 4, 0)
    finally:
        src.close()
        sim.close()


def test_two_lidars_sdk1_and_sdk2_merged_in_a_common_frame():
    """A Mid-70 (SDK 1) and a Mid-360 (SDK 2) see the same room from different poses; through the bundle's
    T_lidar0_lidar1 the second one's clouds land on the first one's points."""
    from radarcal import geometry as g
    from radarcal.bundle import Bundle
    from radarcal.cli.run_cmd import live_lidars

    T_lidar0_lidar1 = g.T_from_xyz_rpy_deg(0.4, -1.2, 0.3, 2.0, -3.0, 25.0)
    b = Bundle()
    b.set_sensor("lidar0", type="lidar")
    b.set_sensor("lidar1", type="lidar")
    b.set_transform("lidar0", "lidar1", T_lidar0_lidar1, method="test")
    disc = _free_port()
    ip0, ip1 = f"127.0.77.{next(_ips)}", f"127.0.78.{next(_ips)}"
    sims = [LivoxSimulator("mid70", ip=ip0, host="127.0.0.1", discovery_port=disc, rate=96_000).start(),
            LivoxSimulator("mid360", ip=ip1, host="127.0.0.1", rate=96_000, T_sensor_scene=np.linalg.inv(T_lidar0_lidar1)).start()]  # fmt: skip
    src = live_lidars(b, [f"lidar0=livox://{ip0}?host=127.0.0.1&discovery_port={disc}", f"lidar1=livox2://{ip1}?host=127.0.0.1"], "lidar0")
    try:
        got: dict[str, list] = {"lidar0": [], "lidar1": []}
        def collect() -> bool:
            for c in src.poll():
                got[c.sensor].append(c)
            return all(len(v) >= 6 for v in got.values())

        assert _wait(collect, 10.0)
        h = src.sensors_health()
        assert h["lidar0"]["sdk"] == 1 and h["lidar1"]["sdk"] == 2 and h["lidar0"]["drops"] == h["lidar1"]["drops"] == 0
    finally:
        src.close()
        for s in sims:
            s.close()
    from scipy.spatial import cKDTree

    p0 = np.concatenate([c.points for c in got["lidar0"][1:]])
    p1 = np.concatenate([c.points for c in got["lidar1"][1:]])
    d, _ = cKDTree(p0).query(p1)
    # both scan the same rosette from the same start time: lidar1's points, moved into lidar0's frame, are lidar0's
    # surfaces: each point has a neighbour within the sampling spacing; without the transform they are metres away
    assert np.median(d) < 0.02 and np.percentile(d, 90) < 0.08  # the sampling density of the surfaces (~1 cm)
    raw = (p1 - T_lidar0_lidar1[:3, 3]) @ T_lidar0_lidar1[:3, :3]  # the clouds as lidar1 sent them (its own frame)
    assert np.median(cKDTree(p0).query(raw)[0]) > 0.3
