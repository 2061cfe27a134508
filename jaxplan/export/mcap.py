"""A run as an MCAP file for Foxglove and any MCAP reader
(`jaxplan export RUN_DIR --format mcap`).

MCAP (the ``mcap`` package's writer: chunked, zstd-compressed, indexed, with CRCs):
JSON-encoded messages (message encoding ``json``) under JSON schemas (schema encoding
``jsonschema``) named after Foxglove's message types, which Foxglove's panels recognise
by name; the schemas hold every field Foxglove's own JSON schemas require.  Log and
publish times are the run's sample times in nanoseconds (the run's t = 0 is the epoch).

Topics:

    /tf                foxglove.FrameTransforms   at each sample: world -> robot_<i>
    /robot_<i>/pose    foxglove.PoseInFrame       at each sample: position in "world"
    /robot_<i>/state   jaxplan_msgs.RobotState    at each sample: position, velocity,
                                                  acceleration (m, m/s, m/s^2), speed
    /robots            foxglove.SceneUpdate       once: each robot's body (a sphere of
                                                  its radius, frame-locked to robot_<i>)
    /goals             foxglove.SceneUpdate       once: each robot's waypoints
    /paths             foxglove.SceneUpdate       once: each robot's sampled path
    /world             foxglove.SceneUpdate       once: the static obstacles and the
                                                  finite workspace faces (thin plates)
    /obstacles         foxglove.SceneUpdate       at each sample, only where some obstacle
                                                  moves: each moving obstacle where it is
                                                  then (World.center_at), entity
                                                  obstacle_<k> (k: its index in the world)
    /metrics           jaxplan_msgs.Metrics       once: metrics.json

plus a metadata record ``jaxplan_run`` (name, backend, success, robots, dimensions,
duration_s) and the run's config.toml and metrics.json as attachments.  The samples are
trajectories.npz's (t, pos, vel, acc: 100 Hz ideal, the control rate under mjx);
orientations are the identity (a run stores no attitude); a planar run lies in z = 0.

    export_mcap(run_dir, out_dir=None) -> report    (out_dir/<name>.mcap)
    mcap_bytes(run) -> bytes                        the file for a RunData
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np

from jaxplan.export.common import ExportError, json_safe, read_run

__all__ = ["SCHEMAS", "export_mcap", "mcap_bytes", "topics"]

FRAME = "world"
PLANAR_HEIGHT_M = 0.5  # m, the height a planar run's obstacles are drawn with
PLATE_M = 0.01  # m, the thickness of a workspace face's plate
MARGIN_M = 1.0  # m, an unbounded axis is drawn over the fleet's extent +- this
_COLORS = ((0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
           (0.58, 0.4, 0.74), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5),
           (0.74, 0.74, 0.13), (0.09, 0.75, 0.81))  # matplotlib's tab10

# ------------------------------------------------------------------ the JSON schemas

_NUM = {"type": "number"}
_BOOL = {"type": "boolean"}
_STR = {"type": "string"}
_NSEC = {"type": "integer", "minimum": 0, "maximum": 999999999}
_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": _NSEC}}
_DURATION = {"type": "object", "title": "duration",
             "properties": {"sec": {"type": "integer"}, "nsec": _NSEC}}


def _obj(title: str, props: dict) -> dict:
    return {"title": title, "type": "object", "properties": props, "required": list(props)}


def _xyz(title: str) -> dict:
    return _obj(title, {"x": _NUM, "y": _NUM, "z": _NUM})


def _array(items: dict) -> dict:
    return {"type": "array", "items": items}


def _enum(title: str, names) -> dict:
    return {"title": title, "oneOf": [{"title": n, "const": i} for i, n in enumerate(names)]}


_VEC3 = _xyz("foxglove.Vector3")
_POINT3 = _xyz("foxglove.Point3")
_QUAT = _obj("foxglove.Quaternion", {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_POSE = _obj("foxglove.Pose", {"position": _VEC3, "orientation": _QUAT})
_COLOR = _obj("foxglove.Color", {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_INDICES = _array({"type": "integer", "minimum": 0})
_PRIMITIVES = {
    "arrows": _obj("foxglove.ArrowPrimitive", {
        "pose": _POSE, "shaft_length": _NUM, "shaft_diameter": _NUM, "head_length": _NUM,
        "head_diameter": _NUM, "color": _COLOR}),
    "cubes": _obj("foxglove.CubePrimitive", {"pose": _POSE, "size": _VEC3, "color": _COLOR}),
    "spheres": _obj("foxglove.SpherePrimitive", {"pose": _POSE, "size": _VEC3, "color": _COLOR}),
    "cylinders": _obj("foxglove.CylinderPrimitive", {
        "pose": _POSE, "size": _VEC3, "bottom_scale": _NUM, "top_scale": _NUM,
        "color": _COLOR}),
    "lines": _obj("foxglove.LinePrimitive", {
        "type": _enum("foxglove.LineType", ("LINE_STRIP", "LINE_LOOP", "LINE_LIST")),
        "pose": _POSE, "thickness": _NUM, "scale_invariant": _BOOL,
        "points": _array(_POINT3), "color": _COLOR, "colors": _array(_COLOR),
        "indices": _INDICES}),
    "triangles": _obj("foxglove.TriangleListPrimitive", {
        "pose": _POSE, "points": _array(_POINT3), "color": _COLOR, "colors": _array(_COLOR),
        "indices": _INDICES}),
    "texts": _obj("foxglove.TextPrimitive", {
        "pose": _POSE, "billboard": _BOOL, "font_size": _NUM, "scale_invariant": _BOOL,
        "color": _COLOR, "text": _STR}),
    "models": _obj("foxglove.ModelPrimitive", {
        "pose": _POSE, "scale": _VEC3, "color": _COLOR, "override_color": _BOOL, "url": _STR,
        "media_type": _STR, "data": {"type": "string", "contentEncoding": "base64"}}),
}
_ENTITY = _obj("foxglove.SceneEntity", {
    "timestamp": _TIME, "frame_id": _STR, "id": _STR, "lifetime": _DURATION,
    "frame_locked": _BOOL,
    "metadata": _array(_obj("foxglove.KeyValuePair", {"key": _STR, "value": _STR})),
    **{k: _array(v) for k, v in _PRIMITIVES.items()}})
_DELETION = _obj("foxglove.SceneEntityDeletion", {
    "timestamp": _TIME, "type": _enum("foxglove.SceneEntityDeletionType", ("MATCHING_ID", "ALL")),
    "id": _STR})
_TRANSFORM = _obj("foxglove.FrameTransform", {
    "timestamp": _TIME, "parent_frame_id": _STR, "child_frame_id": _STR,
    "translation": _VEC3, "rotation": _QUAT})

# schema name -> JSON schema (Foxglove's field names, types and required fields)
SCHEMAS = {
    "foxglove.FrameTransform": _TRANSFORM,
    "foxglove.FrameTransforms": _obj("foxglove.FrameTransforms",
                                     {"transforms": _array(_TRANSFORM)}),
    "foxglove.PoseInFrame": _obj("foxglove.PoseInFrame",
                                 {"timestamp": _TIME, "frame_id": _STR, "pose": _POSE}),
    "foxglove.SceneUpdate": _obj("foxglove.SceneUpdate", {"deletions": _array(_DELETION),
                                                          "entities": _array(_ENTITY)}),
    "jaxplan_msgs.RobotState": _obj("jaxplan_msgs.RobotState", {
        "timestamp": _TIME, "robot": {"type": "integer", "minimum": 0}, "frame_id": _STR,
        "position": _VEC3, "velocity": _VEC3, "acceleration": _VEC3, "speed": _NUM,
        "acceleration_norm": _NUM}),
    "jaxplan_msgs.Metrics": {"title": "jaxplan_msgs.Metrics", "type": "object",
                        "description": "the run's metrics.json (docs/DESIGN.md)"},
}


def topics(num_robots: int, moving: bool = False) -> dict[str, str]:
    """Every topic the file holds -> its schema name (/obstacles where some obstacle
    moves: ``moving``)."""
    out = {"/tf": "foxglove.FrameTransforms", "/robots": "foxglove.SceneUpdate",
           "/goals": "foxglove.SceneUpdate", "/paths": "foxglove.SceneUpdate",
           "/world": "foxglove.SceneUpdate", "/metrics": "jaxplan_msgs.Metrics"}
    if moving:
        out["/obstacles"] = "foxglove.SceneUpdate"
    for i in range(num_robots):
        out[f"/robot_{i}/pose"] = "foxglove.PoseInFrame"
        out[f"/robot_{i}/state"] = "jaxplan_msgs.RobotState"
    return out


# ------------------------------------------------------------------ message builders


def _ns(t: float) -> int:
    return int(round(float(t) * 1e9))


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _v3(p) -> dict:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def _pose(p) -> dict:
    return {"position": _v3(p), "orientation": dict(_IDENTITY)}


def _color(i: int, a: float = 1.0) -> dict:
    r, g, b = _COLORS[i % len(_COLORS)] if i >= 0 else (0.45, 0.45, 0.45)
    return {"r": r, "g": g, "b": b, "a": a}


def _entity(ns: int, ident: str, frame: str = FRAME, frame_locked: bool = False,
            **primitives) -> dict:
    e = {"timestamp": _stamp(ns), "frame_id": frame, "id": ident,
         "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": frame_locked, "metadata": []}
    for key in _PRIMITIVES:
        e[key] = primitives.get(key, [])
    return e


def _text(p, text: str, color: dict) -> dict:
    return {"pose": _pose(p), "billboard": True, "font_size": 14.0, "scale_invariant": True,
            "color": color, "text": text}


def _ball(p, diameter: float, color: dict) -> dict:
    return {"pose": _pose(p), "size": _v3((diameter,) * 3), "color": color}


def _to3(a: np.ndarray) -> np.ndarray:
    """(..., N) positions -> (..., 3): a planar run in z = 0."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape[-1] == 3:
        return a
    return np.concatenate([a, np.zeros(a.shape[:-1] + (3 - a.shape[-1],))], axis=-1)


def _robots_scene(run, ns: int) -> dict:
    ents = []
    for i in range(run.num_robots):
        d = 2.0 * float(run.radius[i])
        ents.append(_entity(ns, f"robot_{i}", frame=f"robot_{i}", frame_locked=True,
                            spheres=[_ball((0, 0, 0), d, _color(i, 0.8))],
                            texts=[_text((0, 0, 0.6 * d + 0.1), f"{i} {run.vehicle[i]}",
                                         _color(i))]))
    return {"deletions": [], "entities": ents}


def _goals_scene(run, ns: int) -> dict:
    wps = run.waypoints if run.waypoints is not None else run.goal[:, None, :]
    ents = []
    for i in range(run.num_robots):
        pts = [p for p in _to3(wps[i]) if np.all(np.isfinite(p))]
        balls = [_ball(p, 0.15, _color(i, 0.6)) for p in pts]
        texts = [_text(p + np.array([0, 0, 0.2]), f"goal {i}" + (f".{w}" if len(pts) > 1 else ""),
                       _color(i)) for w, p in enumerate(pts)]
        ents.append(_entity(ns, f"goal_{i}", spheres=balls, texts=texts))
    return {"deletions": [], "entities": ents}


def _paths_scene(run, ns: int) -> dict:
    pos = _to3(run.pos)
    stride = max(1, int(math.ceil((run.t.size - 1) / max(run.t[-1] - run.t[0], 1e-9) / 100)))
    ents = []
    for i in range(run.num_robots):
        pts = pos[i, ::stride]
        if (run.t.size - 1) % stride:
            pts = np.concatenate([pts, pos[i, -1:]])
        line = {"type": 0, "pose": _pose((0, 0, 0)), "thickness": 0.02,
                "scale_invariant": False, "points": [_v3(p) for p in pts],
                "color": _color(i, 0.7), "colors": [], "indices": []}
        ents.append(_entity(ns, f"path_{i}", lines=[line]))
    return {"deletions": [], "entities": ents}


def _obstacle_shape(w, k: int, center, planar: bool) -> tuple[str, dict]:
    """Obstacle k of world w drawn at ``center`` (3 entries, m): (the SceneEntity's
    primitive list it goes in, the primitive); a planar run's obstacles are
    PLANAR_HEIGHT_M high, a planar sphere a cylinder."""
    from jaxplan.world import BOX, CYLINDER, SPHERE

    gray = _color(-1, 0.6)
    r = float(w.radius[k])
    if w.kind[k] == BOX:
        size = 2.0 * _to3(w.half[k])
        if planar:
            size[2] = PLANAR_HEIGHT_M
        return "cubes", {"pose": _pose(center), "size": _v3(size), "color": gray}
    if w.kind[k] == CYLINDER or (w.kind[k] == SPHERE and planar):
        height = PLANAR_HEIGHT_M if planar else 2.0 * float(w.half[k][-1])
        return "cylinders", {"pose": _pose(center), "size": _v3((2 * r, 2 * r, height)),
                             "bottom_scale": 1.0, "top_scale": 1.0, "color": gray}
    return "spheres", _ball(center, 2.0 * r, gray)


def _moving(run) -> np.ndarray:
    """The indices of the run's moving obstacles (empty where none moves)."""
    w = run.world
    return np.zeros(0, int) if w is None else np.nonzero(w.moving)[0]


def _world_scene(run, ns: int) -> dict:
    from jaxplan.world import face_names

    w = run.world
    planar = run.ndim == 2
    prims = {"spheres": [], "cubes": [], "cylinders": []}
    if w is not None:
        moving = w.moving
        for k in range(w.kind.size):
            if not moving[k]:  # a moving one is /obstacles'
                key, prim = _obstacle_shape(w, k, _to3(w.center[k]), planar)
                prims[key].append(prim)
    ents = [_entity(ns, "obstacles", **prims)]
    plates = _workspace_plates(run, face_names(w) if w is not None else [])
    if plates:
        ents.append(_entity(ns, "workspace", cubes=plates))
    return {"deletions": [], "entities": ents}


def _obstacles_scene(run, ns: int, centers, moving) -> dict:
    """The moving obstacles ``moving`` (indices) at ``centers`` ((K, N) m, every
    obstacle's centre at this time): one entity each, ``obstacle_<k>`` (the same id at
    every sample, so Foxglove replaces it)."""
    w = run.world
    planar = run.ndim == 2
    ents = []
    for k in moving:
        key, prim = _obstacle_shape(w, int(k), _to3(centers[k]), planar)
        ents.append(_entity(ns, f"obstacle_{int(k)}", **{key: [prim]}))
    return {"deletions": [], "entities": ents}


def _workspace_plates(run, faces) -> list[dict]:
    """A thin translucent plate for every finite workspace face, spanning the other
    axes' bounds (an unbounded axis: the fleet's sampled extent +- MARGIN_M)."""
    w = run.world
    if w is None or not faces:
        return []
    n = run.ndim
    pos = run.pos.reshape(-1, n)
    lo = np.where(np.isfinite(w.lo), w.lo, np.minimum(pos.min(0), w.hi) - MARGIN_M)
    hi = np.where(np.isfinite(w.hi), w.hi, np.maximum(pos.max(0), w.lo) + MARGIN_M)
    plates = []
    for axis in range(n):
        for bound in (w.lo[axis], w.hi[axis]):
            if not np.isfinite(bound):
                continue
            c = 0.5 * (lo + hi)
            size = hi - lo
            c[axis], size[axis] = bound, PLATE_M
            c3, s3 = _to3(c), _to3(size)
            if n == 2:
                s3[2] = PLANAR_HEIGHT_M
            plates.append({"pose": _pose(c3), "size": _v3(s3), "color": _color(-1, 0.15)})
    return plates


# ------------------------------------------------------------------------ the file


def mcap_bytes(run) -> bytes:
    """The MCAP file of a run (:class:`jaxplan.files.RunData`; module doc for its
    topics), as bytes."""
    from mcap.writer import Writer

    import jaxplan

    buf = io.BytesIO()
    wr = Writer(buf)
    wr.start(profile="", library=f"jaxplan {jaxplan.__version__}")
    schema_ids = {name: wr.register_schema(name=name, encoding="jsonschema",
                                           data=json.dumps(schema).encode())
                  for name, schema in SCHEMAS.items()}
    chan = {topic: wr.register_channel(topic=topic, message_encoding="json",
                                       schema_id=schema_ids[schema])
            for topic, schema in topics(run.num_robots, _moving(run).size > 0).items()}
    seq = dict.fromkeys(chan, 0)

    def put(topic: str, ns: int, msg: dict) -> None:
        wr.add_message(channel_id=chan[topic], log_time=ns, publish_time=ns,
                       data=json.dumps(msg, separators=(",", ":"), allow_nan=False).encode(),
                       sequence=seq[topic])
        seq[topic] += 1

    ns0 = _ns(run.t[0])
    put("/world", ns0, _world_scene(run, ns0))
    put("/goals", ns0, _goals_scene(run, ns0))
    put("/paths", ns0, _paths_scene(run, ns0))
    put("/robots", ns0, _robots_scene(run, ns0))
    put("/metrics", ns0, json_safe(run.metrics))
    pos, vel, acc = _to3(run.pos), _to3(run.vel), _to3(run.acc)
    speed = np.linalg.norm(vel, axis=-1)
    acc_norm = np.linalg.norm(acc, axis=-1)
    moving = _moving(run)
    centers = run.world.center_at(run.t)[0] if moving.size else None  # (T, K, N)
    for k, t in enumerate(run.t):
        ns = _ns(t)
        stamp = _stamp(ns)
        if moving.size:
            put("/obstacles", ns, _obstacles_scene(run, ns, centers[k], moving))
        put("/tf", ns, {"transforms": [
            {"timestamp": stamp, "parent_frame_id": FRAME, "child_frame_id": f"robot_{i}",
             "translation": _v3(pos[i, k]), "rotation": dict(_IDENTITY)}
            for i in range(run.num_robots)]})
        for i in range(run.num_robots):
            put(f"/robot_{i}/pose", ns, {"timestamp": stamp, "frame_id": FRAME,
                                         "pose": _pose(pos[i, k])})
            put(f"/robot_{i}/state", ns, {
                "timestamp": stamp, "robot": i, "frame_id": FRAME, "position": _v3(pos[i, k]),
                "velocity": _v3(vel[i, k]), "acceleration": _v3(acc[i, k]),
                "speed": float(speed[i, k]), "acceleration_norm": float(acc_norm[i, k])})
    m = run.metrics
    wr.add_metadata("jaxplan_run", {
        "name": run.name, "backend": str(m.get("backend", "")),
        "success": json.dumps(m.get("success")), "robots": str(run.num_robots),
        "dimensions": str(run.ndim), "duration_s": repr(float(run.t[-1] - run.t[0]))})
    for name, media in (("config.toml", "application/toml"),
                        ("metrics.json", "application/json")):
        path = run.run_dir / name
        if path.is_file():
            wr.add_attachment(create_time=0, log_time=ns0, name=name, media_type=media,
                              data=path.read_bytes())
    wr.finish()
    return buf.getvalue()


def export_mcap(run_dir, out_dir=None) -> dict:
    """Write the run in ``run_dir`` as ``<out_dir>/<name>.mcap`` (default ``out_dir``:
    the run directory); returns {format, run, file, bytes, messages, robots, topics}."""
    from jaxplan.files import atomic_write_bytes

    run = read_run(run_dir)
    if not all(np.all(np.isfinite(a)) for a in (run.pos, run.vel, run.acc)):
        raise ExportError(f"{run.run_dir}: trajectories.npz: non-finite samples")
    out = Path(out_dir) if out_dir is not None else run.run_dir
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in run.name) or "run"
    path = out / f"{safe}.mcap"
    data = mcap_bytes(run)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data)
    moving = _moving(run).size > 0
    per_sample = 1 + 2 * run.num_robots + int(moving)
    return {"format": "mcap", "run": str(run.run_dir), "file": str(path), "bytes": len(data),
            "messages": 5 + per_sample * run.t.size, "robots": run.num_robots,
            "topics": topics(run.num_robots, moving)}
