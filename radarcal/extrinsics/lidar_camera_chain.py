"""Several cameras in one bundle: transforms a camera gets through a stereo pair, and paths through the frame graph.

A camera pair solved by ``radarcal intrinsics --right`` stores ``T_cam1_cam0``. When cam1 has no LiDAR extrinsic or
field pose of its own but cam0 has, :func:`refresh_derived` stores ``T_cam1_X = T_cam1_cam0 · T_cam0_X`` (X = a LiDAR
or the field) **marked as derived**: ``residual.derived_from`` lists the stored entries it was chained from and
``method`` starts with ``derived:``. A calibration of cam1's own (``lidar-camera --camera cam1``, ``field-pnp --camera
cam1``) replaces it; a derived entry whose sources changed is recomputed and one whose sources are gone is removed.

Pure bundle-graph code (no I/O): the calibration commands call :func:`refresh_derived` before they save.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from radarcal import geometry

__all__ = ["DERIVED_KEY", "is_derived", "own_entry", "chain", "refresh_derived"]

DERIVED_KEY = "derived_from"  # residual key of a derived entry: the names of the entries it was chained from


def is_derived(entry) -> bool:
    """True for an entry :func:`refresh_derived` wrote (not measured by a calibration of its own)."""
    return bool((entry.residual or {}).get(DERIVED_KEY))


def own_entry(bundle, a: str, b: str):
    """The stored, not derived entry between frames ``a`` and ``b`` (either direction), or None."""
    for name in (f"T_{a}_{b}", f"T_{b}_{a}"):
        e = bundle.transforms.get(name)
        if e is not None and not is_derived(e):
            return e
    return None


def chain(bundle, target: str, source: str, avoid: tuple[str, ...] = (), nodes: set[str] | None = None, derived: bool = False):
    """``(T_target_source, [entry names])`` along the shortest path of stored entries, or None when there is none.

    ``avoid``: frames the path must not pass through (e.g. ``"field"`` for a link between two cameras that does not
    use their field poses); ``nodes``: when given, the only frames the path may pass through (besides the ends);
    ``derived``: also walk derived entries (default: only measured ones)."""
    if target == source:
        return np.eye(4), []
    graph: dict[str, list[tuple[str, np.ndarray, str]]] = {}
    for name, e in sorted(bundle.transforms.items()):
        if is_derived(e) and not derived:
            continue
        graph.setdefault(e.target, []).append((e.source, np.asarray(e.T, float), name))
        graph.setdefault(e.source, []).append((e.target, geometry.invert_T(e.T), name))
    seen = {target: (np.eye(4), [])}
    queue = deque([target])
    while queue:
        node = queue.popleft()
        T_t_node, names = seen[node]
        for nxt, T_node_nxt, name in graph.get(node, []):
            if nxt in seen or (nxt != source and (nxt in avoid or (nodes is not None and nxt not in nodes))):
                continue
            seen[nxt] = (T_t_node @ T_node_nxt, names + [name])
            if nxt == source:
                return seen[nxt]
            queue.append(nxt)
    return None


def refresh_derived(bundle, command: str = "") -> list[str]:
    """Store / update / remove the derived camera transforms (see the module docstring); returns one line per change."""
    from radarcal.bundle import Provenance

    cams = set(bundle.cameras)
    others = set()
    for e in bundle.transforms.values():
        if not is_derived(e):
            for a, o in ((e.target, e.source), (e.source, e.target)):
                if a in cams and o not in cams:
                    others.add(o)
    wanted: dict[str, tuple[str, str, np.ndarray, list[str]]] = {}
    for cam in sorted(cams):
        for x in sorted(others):
            if own_entry(bundle, cam, x) is not None:
                continue
            best = None
            for partner in sorted(cams - {cam}):
                if own_entry(bundle, partner, x) is None:
                    continue
                link = chain(bundle, cam, partner, nodes=cams)  # camera-camera (stereo) entries only
                if link is not None and (best is None or len(link[1]) < len(best[1])):
                    own = own_entry(bundle, partner, x)
                    T_partner_x = own.T if own.target == partner else geometry.invert_T(own.T)
                    best = (link[0] @ T_partner_x, link[1] + [own.name])
            if best is not None:
                wanted[f"T_{cam}_{x}"] = (cam, x, best[0], best[1])
    changes = []
    for name, e in list(bundle.transforms.items()):
        if is_derived(e) and name not in wanted:
            bundle.transforms.pop(name)
            changes.append(f"removed {name} (derived from {' · '.join(e.residual[DERIVED_KEY])}: a source is gone or {e.target} now has its own)")
    for name, (cam, x, T, names) in wanted.items():
        old = bundle.transforms.get(name)
        if old is not None and is_derived(old) and list(old.residual[DERIVED_KEY]) == names and np.allclose(old.T, T, rtol=0, atol=1e-12):
            continue
        bundle.set_transform(cam, x, T, method=f"derived: {' · '.join(names)} ({cam} has no calibration of its own)", residual={DERIVED_KEY: names},
                             provenance=Provenance(command=command or "derived"))
        changes.append(f"{'updated' if old is not None else 'derived'} {name} = {' · '.join(names)}")
    return changes
