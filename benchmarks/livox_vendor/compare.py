"""py-livox2 (vendor SDK2) vs radarcal's LivoxSource against the simulator, inside an isolated network namespace."""

import json, os, sys, time, subprocess, tempfile
import numpy as np

which = sys.argv[1]
secs = float(sys.argv[2])
sim = subprocess.Popen(
    [
        sys.executable,
        "-c",
        f"""
import time, sys
from radarcal.synth.livox_sim import LivoxSimulator
s = LivoxSimulator('mid360', ip='10.99.0.2', host='10.99.0.1', discovery_bind='0.0.0.0').start()
t0 = time.monotonic()
while time.monotonic() - t0 < {secs + 8}: time.sleep(0.1)
s.close(); print(s.packets_sent, s.points_sent, s.handshakes, flush=True)
""",
    ],
    stdout=subprocess.PIPE,
    text=True,
    cwd=str(__import__("pathlib").Path(__file__).resolve().parents[2]),
)
time.sleep(1.0)
count = {"pk": 0, "pts": 0}
if which == "vendor":
    sys.path.insert(0, os.environ.get("PY_LIVOX2_DIR", "/tmp/pl2/x"))
    import livox_sdk

    cfg = {
        "MID360": {
            "lidar_net_info": {"cmd_data_port": 56100, "push_msg_port": 56200, "point_data_port": 56300, "imu_data_port": 56400, "log_data_port": 56500},
            "host_net_info": [{"host_ip": "10.99.0.1", "multicast_ip": "", "cmd_data_port": 56101, "push_msg_port": 56201, "point_data_port": 56301, "imu_data_port": 56401, "log_data_port": 56501}],
        }
    }
    path = tempfile.mktemp(suffix=".json")
    json.dump(cfg, open(path, "w"))
    livox_sdk.DisableLivoxSdkConsoleLogger()

    def info(handle, dev):
        print("lidar", handle, dev, flush=True)
        livox_sdk.SetLivoxLidarWorkMode(handle, 1)

    livox_sdk.SetLivoxLidarInfoChangeCallback(info)
    ok = livox_sdk.LivoxLidarSdkInit(path)
    print("init", ok, flush=True)

    def cb(packet):
        raw = packet.get_pts_data()
        a = np.frombuffer(raw, np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1"), ("t", "u1")]))
        count["pk"] += 1
        count["pts"] += int(np.any(np.stack([a["x"], a["y"], a["z"]], -1) != 0, axis=1).sum())

    livox_sdk.SetLivoxLidarPointCloudCallBack(cb)
    t_end = time.monotonic() + secs + 3
    while time.monotonic() < t_end and count["pk"] == 0:
        time.sleep(0.05)
    c0, p0, w0 = time.process_time(), count["pts"], time.monotonic()
    time.sleep(secs)
    c1, p1, w1 = time.process_time(), count["pts"], time.monotonic()
    time.sleep(max(0, secs + 9 - (time.monotonic() - w0)))
    livox_sdk.LivoxLidarSdkUninit()
else:
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))
    from radarcal.io.livox import LivoxSource

    src = LivoxSource("10.99.0.2", sdk=2, host="10.99.0.1").start()
    t_end = time.monotonic() + secs + 3
    while time.monotonic() < t_end and src.health.packets == 0:
        time.sleep(0.05)
    c0, p0, w0 = time.process_time(), src.health.points, time.monotonic()
    while time.monotonic() - w0 < secs:
        src.poll()
        time.sleep(0.05)
    c1, p1, w1 = time.process_time(), src.health.points, time.monotonic()
    while sim.poll() is None:
        src.poll()
        time.sleep(0.05)
    time.sleep(0.3)
    src.poll()
    count = {"pk": src.health.packets, "pts": src.health.points}
    src.close()
out = sim.communicate()[0].split()
print(
    json.dumps(
        {
            "which": which,
            "cpu_core_fraction": (c1 - c0) / (w1 - w0),
            "pts_per_s": (p1 - p0) / (w1 - w0),
            "received_packets": count["pk"],
            "received_points": count["pts"],
            "sent_packets": int(out[0]) if out else None,
            "sent_points": int(out[1]) if out else None,
        }
    )
)
