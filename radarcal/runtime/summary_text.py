"""The human lines of ``radarcal run``'s summary (the CLI prints them; ``--json`` prints the summary itself)."""

from __future__ import annotations


def run_summary_lines(s: dict) -> list[str]:
    """Lines for a :func:`radarcal.runtime.match_run` summary dict: frames, latency, positions, accuracy, outputs."""
    out = []
    cams = ", ".join(f"{c}{' (missing ' + str(s['camera_missing_frames'][c]) + ' frames)' if s['camera_missing_frames'].get(c) else ''}" for c in s["cameras"]) if s.get("cameras") else s["camera"]
    out.append(f"{s['frames']} frames in {s['wall_s']:.1f} s ({s['fps']:.1f} FPS), {s['clouds']} clouds; camera {cams}, lidar {s['lidar'] or '-'}")
    out.append("  latency ms (median / p95): " + ", ".join(f"{k} {v['median']:.2f}/{v['p95']:.2f}" for k, v in s["latency_ms"].items()))
    rf = s["robot_frames"]
    out.append(f"  robot positions: {rf.get('depth', 0)} from LiDAR depth, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted")
    rw = s.get("roi_windows")
    if rw:
        out.append(f"  far-robot windows ({rw['max_windows']} per frame, {rw['input'][1]}x{rw['input'][0]} native): {rw['windows_run']} windows on {rw['frames_with_windows']} camera frames, "
                   f"{rw['boxes_added']} boxes more than the full frames")
    acc = s.get("accuracy")
    if acc and acc["median_m"] is not None:
        out.append(f"  vs truth: {acc['located']}/{acc['visible']} visible robots located; error median {acc['median_m']:.3f} m, p95 {acc['p95_m']:.3f} m, max {acc['max_m']:.3f} m")
        out.append(f"  right label within 0.6 m {acc['right_within_0.6m_pct']:.1f} %, false robots {acc['false_per_frame']:.3f} per frame, wrong label "
                   f"{acc['wrong_label_pct'] or 0:.2f} %, any track within 0.3 m of a LiDAR-seen robot {acc['lidar_within_0.3m_pct'] or 0:.1f} %, longest ghost {acc['longest_ghost_s']:.2f} s")
    elif acc:
        out.append(f"  vs truth: any track within 0.3 m of a LiDAR-seen robot {acc['lidar_within_0.3m_pct'] or 0:.1f} %, false robots {acc['false_per_frame']:.3f} per frame, longest ghost {acc['longest_ghost_s']:.2f} s")
    if s.get("bad_frames") or s.get("skipped_inputs"):
        out.append(f"  skipped: {s['bad_frames']} unreadable frames, {s['skipped_inputs']} unreadable clouds/messages (warnings on stderr)")
    for key, what in (("out", "tracks"), ("minimap", "minimap")):
        if s.get(key):
            out.append(f"  {what} -> {s[key]}")
    if s.get("serial"):
        q = s["serial"]
        out.append(f"  referee link {q['port']}: {q.get('sent', 0)} frames sent, {q['disconnects']} disconnects{', last error ' + q['last_error'] if q['last_error'] else ''}")
    if s.get("drift") and s["drift"]["max"]:
        d = s["drift"]
        out.append(f"  LiDAR drift: {d['checks']} checks every {d['check_every_s']:g} s, largest {d['max']['cm']:.1f} cm / {d['max']['deg']:.3f} deg (t={d['max']['t']:.1f} s), {'MOVED' if d['moved'] else 'within'} {d['threshold_cm']:.0f} cm / {d['threshold_deg']:g} deg")
    for w in s["warnings"]:
        out.append(f"  warning: {w}")
    return out
