"""Calibration-image libraries: N stereo pairs of a target in random poses, rendered through the
normal pipeline, with per-pair ground truth and the true rig calibration.

Layout of a library directory::

    library.json          what was made: every setting that shapes the images (target, cameras,
                          poses spec, render options, seed, noise, blur, lighting)
    rig.yaml              the true calibration, OpenCV FileStorage (see :func:`glsim.io.calibfiles.write_rig_yaml`)
    pairs/0000_cam0.tif   images, one per camera (8-bit TIFF for 8-bit cameras)
    pairs/0000.json       the pair's ground truth and its images' SHA-256, written last (a pair is
                          done when it exists)

Broken files are named, never passed over: :func:`load_library` checks library.json and every
pair JSON (valid JSON, the keys and array lengths the target needs); a rerun with other
settings names each that differs.

The paper's Table 8 set-up is :func:`paper_rig`; its names map to OpenCV's as in
docs/calib.md (Kappa 1/2 are k1/k2 on normalized coordinates, not px⁻²).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from glsim.io import images as io
from glsim.io.cameras import camera_from_dict, camera_to_dict
from glsim.io.calibfiles import opencv_distortion, stereo_extrinsics, write_rig_yaml
from glsim.io.hashes import sha256_file
from glsim.scene.camera import Camera, Distortion, project, stereo_pose
from glsim.errors import SceneError
from glsim.render import Renderer
from glsim.scene import Noise, Render, Scene
from glsim.scene.model import recorded
from glsim.workflows.calib import poses as posemod
from glsim.workflows.calib.targets import Charuco, Chessboard, Defects, DotGrid, plate_mesh, reference

FORMAT_VERSION = 2     # 2: noise, blur and lighting recorded; pair JSONs hold settings and image checksums
OUTLINE_POINTS = 512   # polygon vertices per dot outline for the true image centroid
REFERENCE_PX_PER_IMAGE_PX = 4   # auto_px_per_mm: reference pixels per image pixel at the nearest pose
EFFECTS = ("blur", "lighting")  # scene effects a library may take (write_library's ``effects``)
MANIFEST_KEYS = ("format", "seed", "n_pairs", "target", "cameras", "poses", "render", "noise")
PAIR_KEYS = ("pair", "kind", "R", "t", "cameras")

# Table 8 of the reference paper: camera 0 and 1 intrinsics, stereo extrinsics (mm, degrees).
PAPER_CAMERAS = ({"fx": 2900.0, "k1": -0.46, "k2": -0.166}, {"fx": 3115.0, "k1": -0.35, "k2": -0.01})
PAPER_PRINCIPAL_POINT = (812.0, 617.0)
PAPER_SIZE = (1624, 1234)
PAPER_STEREO = {"Tx": 144.0, "Ty": -12.8, "Tz": 60.0, "Theta": -1.85, "Phi": -22.8, "Psi": -1.9}

NoiseHook = Callable[[np.ndarray, Camera, int], np.ndarray]


def paper_rig(scale: float = 1.0, bit_depth: int = 8) -> tuple[Camera, Camera]:
    """The Table 8 stereo rig, optionally scaled to ``scale`` × 1624×1234 px.

    Scaling keeps the optics: focal lengths scale by ``scale`` and the principal point keeps
    its place on the sensor (c' = (c + ½)·scale − ½ in pixel-centre coordinates); distortion
    coefficients (on normalized coordinates) are unchanged. The axes converge ≈ 372 mm in
    front of camera 0.
    """
    if not scale > 0:
        raise SceneError("scale", f"must be > 0, got {scale}", "give the image-size factor, e.g. 0.25")
    W, H = (int(round(n * scale)) for n in PAPER_SIZE)
    cx, cy = ((c + 0.5) * scale - 0.5 for c in PAPER_PRINCIPAL_POINT)
    R2, t2 = stereo_pose(np.eye(3), np.zeros(3), *PAPER_STEREO.values())
    poses = ((np.eye(3), np.zeros(3)), (R2, t2))
    return tuple(Camera(name=f"cam{i}", size=(W, H), fx=p["fx"] * scale, fy=p["fx"] * scale, cx=cx, cy=cy,
                        distortion=Distortion(k1=p["k1"], k2=p["k2"]), R=tuple(map(tuple, R)), t=tuple(t),
                        bit_depth=bit_depth)
                 for i, (p, (R, t)) in enumerate(zip(PAPER_CAMERAS, poses)))


def auto_px_per_mm(cameras, spec: posemod.PoseSpec = posemod.PoseSpec(), floor: float = 10.0) -> float:
    """A target reference resolution (px/mm) with ≥ REFERENCE_PX_PER_IMAGE_PX reference pixels
    per image pixel where a camera sees the target largest (the rig's working distance less
    the plunge), and at least ``floor``.

    A coarser reference shows through: its pixels, interpolated, move every dot edge by a few
    hundredths of a pixel depending on where the edge falls on the reference grid. A grey-level
    centroid does not see that (it keeps the first moment); an edge-based estimator does: at
    10 px/mm and 1624×1234 (0.78 image px per reference px) the model fit errs by 0.004 px
    mean without noise, at 40 px/mm by 0.0007 px (docs/calib.md).
    """
    cams = tuple(cameras)
    B, o = posemod.rig_frame(cams)
    o_world = (o - cams[0].translation) @ cams[0].rotation          # camera 0 → world
    mm_per_px = []
    for cam in cams:
        depth = float((cam.rotation @ o_world + cam.translation)[2]) * (1 - spec.plunge)
        mm_per_px.append(depth / max(cam.fx, cam.fy))
    return float(max(floor, math.ceil(REFERENCE_PX_PER_IMAGE_PX / min(mm_per_px))))


# --- ground truth ---------------------------------------------------------------------------

def to_world(R, t, cam1: Camera) -> tuple[np.ndarray, np.ndarray]:
    """A target pose given in camera 0's frame as a target → world pose."""
    R1, t1 = cam1.rotation, cam1.translation
    return R1.T @ np.asarray(R, float), R1.T @ (np.asarray(t, float) - t1)


def polygon_centroid(p: np.ndarray) -> np.ndarray:
    """Area centroids (..., 2) of closed polygons (..., n, 2) (shoelace formula)."""
    q = np.roll(p, -1, axis=-2)
    cross = p[..., 0] * q[..., 1] - q[..., 0] * p[..., 1]
    area = cross.sum(-1) / 2
    return np.stack([((p[..., 0] + q[..., 0]) * cross).sum(-1), ((p[..., 1] + q[..., 1]) * cross).sum(-1)],
                    axis=-1) / (6 * area[..., None])


def dot_truth(target: DotGrid, R_world, t_world, cam: Camera) -> dict[str, np.ndarray]:
    """Where ``cam`` sees each printed dot of ``target`` placed by (R_world, t_world).

    ``projected``: the projection of the dot centre (px); ``centroid``: the area centroid of
    the dot's (distorted) image, a 512-gon through the projected outline — the quantity a
    grey-level centroid measures; ``visible``: the whole outline projects inside the image
    (1 px clear of its edge) onto the printed face.
    """
    centres = target.true_points()
    a = np.linspace(0.0, 2 * np.pi, OUTLINE_POINTS, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a), 0 * a], axis=1)
    outline = centres[:, None, :] + target.diameters()[:, None, None] / 2 * ring     # (N, n, 3)
    R, t = np.asarray(R_world, float), np.asarray(t_world, float)
    uv_c, ok_c = project(centres @ R.T + t, cam)
    uv_o, ok_o = project(outline @ R.T + t, cam)
    W, H = cam.size
    inside = ok_o & (uv_o[..., 0] >= 1) & (uv_o[..., 0] <= W - 2) & (uv_o[..., 1] >= 1) & (uv_o[..., 1] <= H - 2)
    normal = R[:, 2]                                   # target z: into the plate
    front = float(normal @ (cam.center - t)) < 0.0
    return {"projected": np.where(ok_c[:, None], uv_c, np.nan),
            "centroid": np.where(ok_o.all(1)[:, None], polygon_centroid(uv_o), np.nan),
            "visible": inside.all(axis=1) & front}


# --- files -----------------------------------------------------------------------------------

def target_to_dict(target) -> dict:
    return {"type": type(target).__name__, **dataclasses.asdict(target)}


def target_from_dict(d: dict, where: str = "library.json"):
    """The target a manifest's ``target`` entry describes; SceneError naming ``where``."""
    try:
        d = dict(d)
        kind = d.pop("type")
        if kind == "DotGrid":
            d["defects"] = Defects(**d["defects"])
            d["markers"] = tuple(tuple(m) for m in d["markers"])
            return DotGrid(**d)
        classes = {"Chessboard": Chessboard, "Charuco": Charuco}
        if kind not in classes:
            raise SceneError(f"{where}: target.type", f"{kind!r} is unknown", "use DotGrid, Chessboard or Charuco")
        return classes[kind](**d)
    except (TypeError, KeyError, ValueError) as exc:
        if isinstance(exc, SceneError):
            raise
        raise SceneError(f"{where}: target", f"is not a target description ({type(exc).__name__}: {exc})",
                         "restore the file, or make the library again with `glsim calib library`") from None


def read_camera(d: dict, where: str = "library.json") -> Camera:
    """A camera of library.json, or a SceneError naming the file."""
    try:
        return camera_from_dict(d)
    except (TypeError, KeyError, ValueError) as exc:
        if isinstance(exc, SceneError):
            raise
        raise SceneError(f"{where}: cameras", f"hold no camera description ({type(exc).__name__}: {exc})",
                         "restore the file, or make the library again with `glsim calib library`") from None


def write_true_rig(path, cam1: Camera, cam2: Camera) -> Path:
    R, T = stereo_extrinsics(cam1, cam2)
    return write_rig_yaml(path, cam1.K, opencv_distortion(cam1), cam2.K, opencv_distortion(cam2), R, T, cam1.size)


# --- the library -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Library:
    """A library read back: where it is, what it holds, and each done pair's ground truth."""
    directory: Path
    target: object
    cameras: tuple[Camera, ...]
    pairs: tuple[dict, ...]
    manifest: dict

    def image_path(self, pair: dict, cam: Camera) -> Path:
        return self.directory / "pairs" / pair["cameras"][cam.name]["image"]


def pair_name(i: int) -> str:
    return f"{i:04d}"


def _render_options(scene_or_rig) -> tuple[tuple[Camera, ...], Render]:
    if isinstance(scene_or_rig, Scene):
        return scene_or_rig.cameras, scene_or_rig.render
    cams = tuple(scene_or_rig)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise SceneError("rig", "is neither a Scene nor a sequence of Cameras", "pass scene or paper_rig()")
    return cams, Render(mode="exact", samples_per_pixel=16)


def _effects(rig, effects) -> dict:
    """The scene effects a library takes: {"blur": Optics | None, "lighting": Lighting | None}."""
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        raise SceneError("effects", f"{bad} are not among {EFFECTS}", "ask for blur and/or lighting")
    out = {"blur": None, "lighting": None}
    for name, attr, table in (("blur", "optics", "[optics]"), ("lighting", "lighting", "[lighting]")):
        if name in effects:
            value = getattr(rig, attr, None) if isinstance(rig, Scene) else None
            if value is None:
                raise SceneError(f"effects.{name}", f"was asked for, but the rig has no {table} table",
                                 f"give a scene TOML with an {table} table (the paper rig 'default' has none)")
            out[name] = value
    return out


def _noise_record(noise) -> dict | None:
    """What library.json records of a noise setting: the Noise parameters, or a hook's name."""
    if noise is None:
        return None
    if isinstance(noise, Noise):
        return dataclasses.asdict(noise)
    if callable(noise):
        return {"hook": getattr(noise, "__qualname__", type(noise).__name__)}
    raise SceneError("noise", f"{noise!r} is neither a glsim.scene.Noise nor a callable",
                     "pass Noise(sigma=2) (2 % Gaussian) or a function (image, camera, seed) -> image")


def _noise_function(noise):
    if noise is None or not isinstance(noise, Noise):
        return noise
    from glsim.effects.noise import add_noise
    return lambda image, cam, seed: add_noise(image, noise, cam.bit_depth, seed)


def _json_ready(x):
    return json.loads(json.dumps(x))


def _canonical(x):
    """Numbers as floats (2 and 2.0 are the same setting), containers recursively."""
    if isinstance(x, dict):
        return {k: _canonical(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_canonical(v) for v in x]
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return float(x)
    return x


def settings_hash(manifest: dict) -> str:
    """SHA-256 of a manifest's image-shaping settings (everything but n_pairs and timing; numbers
    compared as floats): each pair JSON carries it, so pairs made with other settings are found
    even without library.json."""
    keep = {k: v for k, v in manifest.items() if k not in ("seconds_per_pair", "n_pairs")}
    return hashlib.sha256(json.dumps(_canonical(keep), sort_keys=True).encode()).hexdigest()


# library.json key → how `glsim calib library` sets it (for messages)
_HOW = {"seed": "--seed", "noise": "--noise (or the scene's [noise])", "target": "--rows/--cols/--pitch/--dot/"
        "--sigma/--pitch-error/--target-seed/--px-per-mm", "cameras": "the scene or --scale",
        "poses": "--fov", "render": "--spp or the scene's [render]", "blur": "--blur (the scene's [optics])",
        "lighting": "--lighting (the scene's [lighting])", "format": "the glsim version that made it"}


def _short(x, n: int = 60) -> str:
    t = json.dumps(x, sort_keys=True)
    return t if len(t) <= n else t[:n - 1] + "…"


def settings_differences(old: dict, new: dict) -> list[str]:
    """One line per image-shaping setting that differs between two manifests, naming the first
    differing entry inside it: "noise.sigma: 2.0 in the library, 0.0 asked (--noise …)"."""
    out = []

    def first(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b)):
                if a.get(k, "<none>") != b.get(k, "<none>"):
                    return first(a.get(k, "<none>"), b.get(k, "<none>"), f"{path}.{k}")
        if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
            for i, (x, y) in enumerate(zip(a, b)):
                if x != y:
                    return first(x, y, f"{path}[{i}]")
        return path, a, b

    for key in sorted((set(old) | set(new)) - {"seconds_per_pair", "n_pairs"}):
        a, b = old.get(key, "<none>"), new.get(key, "<none>")
        if a != b:
            path, x, y = first(a, b, key)
            out.append(f"{path}: {_short(x)} in the library, {_short(y)} asked ({_HOW.get(key, key)})")
    return out


def write_library(rig, target, n_pairs: int, out_dir, seed: int = 0, backend: str | None = None,
                  spec: posemod.PoseSpec = posemod.PoseSpec(), noise=None, ctx=None,
                  progress: Callable[[int, int], None] | None = None, effects=(), workers: int = 1,
                  scheduler: str | None = None) -> Library:
    """Render ``n_pairs`` poses of ``target`` seen by every camera of ``rig`` into ``out_dir``.

    ``rig``: a Scene (its cameras and [render] options are used) or cameras such as
    :func:`paper_rig` (then exact mode, 16 samples per pixel). ``noise``: a
    :class:`glsim.scene.Noise` (e.g. Noise(sigma=2), Table 8's 2 %), or a hook
    ``noise(image, camera, seed)`` returning the noisy float image before quantisation
    (recorded by its name only); the seed is distinct per (library seed, pair, camera).
    ``effects``: any of "blur", "lighting" — the Scene rig's [optics] / [lighting] applied to
    every image. Every setting that shapes the images is recorded in library.json. Pairs
    already written (their JSON exists, made with the same settings) are kept, so an
    interrupted run resumes and a larger ``n_pairs`` extends the library; other settings raise
    SceneError naming each that differs. Same seed, same library.

    ``workers`` > 1 or ``scheduler`` (a Dask ``tcp://HOST:PORT``) render the pairs on the image
    library's engine (:func:`glsim.workflows.library.runner.execute`: a local process pool whose
    dead workers are replaced, or a Dask cluster), a few pairs per task, each worker keeping
    one renderer: the same bytes as in this process. ``noise`` must then be a Noise (a hook
    cannot be sent to other processes), and ``ctx`` is not used.
    """
    if not isinstance(n_pairs, (int, np.integer)) or n_pairs < 1:
        raise SceneError("pairs", f"must be an integer ≥ 1, got {n_pairs!r}", "give the number of stereo pairs")
    cams, opts = _render_options(rig)
    fx = _effects(rig, effects)
    out = Path(out_dir)
    half = _half_size(target)
    all_poses = posemod.make_poses(cams, half, n_pairs, spec, seed)
    manifest = _json_ready({"format": FORMAT_VERSION, "seed": seed, "n_pairs": n_pairs,
                            "target": target_to_dict(target), "cameras": [camera_to_dict(c) for c in cams],
                            "poses": dataclasses.asdict(spec), "render": recorded("render", dataclasses.asdict(opts)),
                            "noise": _noise_record(noise),
                            "blur": None if fx["blur"] is None else dataclasses.asdict(fx["blur"]),
                            "lighting": None if fx["lighting"] is None else dataclasses.asdict(fx["lighting"])})
    settings = settings_hash(manifest)
    existing = out / "library.json"
    if existing.is_file():
        old = _read_json(existing, "library.json of a calibration library",
                         "restore it, or delete it and rerun `glsim calib library` with the settings the library was "
                         "made with (its pairs are checked against them)")
        diff = settings_differences(old, manifest)
        if diff:
            raise SceneError(str(existing), "was made with other settings: " + "; ".join(diff),
                             "write to another directory, or repeat the library's settings (only --pairs may grow)")
        if n_pairs < old.get("n_pairs", 0):
            raise SceneError(str(existing), f"holds {old['n_pairs']} pairs, {n_pairs} asked: a library is never "
                             "shrunk (other settings are the same)", f"ask for ≥ {old['n_pairs']} pairs, or use "
                             "another directory")
        if "seconds_per_pair" in old:
            manifest["seconds_per_pair"] = old["seconds_per_pair"]
    done = set()
    for path in sorted((out / "pairs").glob("[0-9]*.json")):     # pairs kept must be this library's
        pair = _read_json(path, "pair ground truth", _pair_fix(path))
        if pair.get("settings_sha256", settings) != settings:
            raise SceneError(str(path), "was made with other settings than those asked (its settings_sha256 "
                             "differs; library.json may have been replaced)", "write to another directory, or "
                             "repeat the settings the library was made with")
        done.add(path.stem)
    io.write_text(existing, json.dumps(manifest, indent=1))
    if len(cams) == 2:
        write_true_rig(out / "rig.yaml", cams[0], cams[1])
    world = [to_world(p.R, p.t, cams[0]) for p in all_poses]
    todo = [i for i in range(n_pairs) if pair_name(i) not in done]
    scene = Scene(cameras=cams, render=opts, optics=fx["blur"], lighting=fx["lighting"])
    if workers > 1 or scheduler:
        seconds = _render_on_engine(scene, target, manifest, settings, todo, out, backend, workers, scheduler,
                                    progress)
    else:
        add = _noise_function(noise)
        seconds = []
        with _pair_renderer(scene, backend, ctx, target, world) as r:
            for n_done, i in enumerate(todo, 1):
                seconds.append(render_pair(r, target, all_poses[i], world[i], i, settings, seed, add, out))
                if progress:
                    progress(n_done, len(todo))
    if seconds:   # the median of this run's pairs
        io.write_text(existing, json.dumps({**manifest, "seconds_per_pair": float(np.median(seconds))}, indent=1))
    return load_library(out)


def _pair_renderer(scene: Scene, backend: str | None, ctx, target, world) -> Renderer:
    """The renderer of a library: the target's reference image on a plate mesh whose load
    step i + 1 is pose i (``world``: (R, t) per pose)."""
    return Renderer(scene, backend, ctx=ctx, mesh=plate_mesh(target, world), reference=reference(target))


def render_pair(r: Renderer, target, pose, world_pose, i: int, settings: str, seed: int, add, out: Path) -> float:
    """Render pair ``i`` (load step i + 1 of the renderer's plate mesh) into ``out/pairs``: every
    camera's image, then the pair's ground-truth JSON, written last (a pair is done when its
    JSON exists). Returns the seconds it took."""
    t0 = time.perf_counter()
    Rw, tw = world_pose
    record = {"pair": i, "kind": pose.kind, "cell": pose.cell, "R": pose.R, "t": pose.t, "rvec": pose.rvec.tolist(),
              "points_world": (target.true_points() @ Rw.T + tw).tolist(), "cameras": {},
              "settings_sha256": settings}
    for k, cam in enumerate(r.scene.cameras):
        image = r.render(cam.name, step=i + 1).image
        if add is not None:
            image = add(image, cam, _noise_seed(seed, i, k))
        name = f"{pair_name(i)}_{cam.name}.tif"
        path = io.write_image(out / "pairs" / name, image, cam.bit_depth)
        truth = dot_truth(target, Rw, tw, cam) if isinstance(target, DotGrid) else _corner_truth(target, Rw, tw, cam)
        record["cameras"][cam.name] = {"image": name, "sha256": sha256_file(path),
                                       **{key: v.tolist() for key, v in truth.items()},
                                       "complete": bool(truth["visible"].all())}
    io.write_text(out / "pairs" / f"{pair_name(i)}.json", json.dumps(record))
    return time.perf_counter() - t0


PAIRS_PER_TASK = 2


def _render_on_engine(scene: Scene, target, manifest: dict, settings: str, todo: list[int], out: Path,
                      backend: str | None, workers: int, scheduler: str | None, progress) -> list[float]:
    """The pairs ``todo`` as tasks of :func:`render_pairs` on the library engine; their seconds."""
    from glsim.workflows.library import runner

    if manifest["noise"] is not None and "hook" in manifest["noise"]:
        raise SceneError("noise", f"is a hook ({manifest['noise']['hook']}), which cannot be sent to worker processes",
                         "pass a glsim.scene.Noise, or render with workers=1 and no scheduler")
    tasks = [{"out": str(out), "scene": scene.to_json(), "manifest": manifest, "settings": settings,
              "backend": backend or scene.render.backend, "pairs": todo[k:k + PAIRS_PER_TASK]}
             for k in range(0, len(todo), PAIRS_PER_TASK)]
    summary = runner.Summary(out=str(out), total=len(todo), workers=max(1, min(workers, len(tasks))),
                             engine="dask" if scheduler else "local")
    seconds, failed = [], []

    def on_done(task, result):
        status, payload = result
        if status == "error":
            failed.append((task["pairs"], payload))
            return
        seconds.extend(payload)
        if progress:
            progress(len(seconds), len(todo))

    runner.execute(tasks, render_pairs, on_done, summary, scheduler, key="calib-" + settings)
    if failed:
        raise SceneError(str(out), "pairs " + "; ".join(f"{p}: {m}" for p, m in failed) + " were not rendered",
                         "run the same command again to render what is missing (pairs written are kept)")
    return seconds


def _pose_spec(d: dict) -> posemod.PoseSpec:
    """The PoseSpec library.json records (its lists back to tuples)."""
    return posemod.PoseSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def render_pairs(task: dict) -> list[float]:
    """Worker side of :func:`_render_on_engine`: render ``task["pairs"]`` of the library in
    ``task["out"]`` with this worker thread's renderer for the library's settings (made once:
    the target's reference image and the plate mesh over every pose); the seconds per pair."""
    from glsim.scene.load import from_resolved
    from glsim.scene import scene_from_dict
    from glsim.workflows.library import worker

    m, settings = task["manifest"], task["settings"]
    scene = scene_from_dict(*from_resolved(json.loads(task["scene"])))
    target = target_from_dict(m["target"])
    poses = posemod.make_poses(scene.cameras, _half_size(target), m["n_pairs"], _pose_spec(m["poses"]),
                               m["seed"])
    world = [to_world(p.R, p.t, scene.cameras[0]) for p in poses]
    backend = task["backend"]
    r = worker.thread_renderer(f"calib:{settings}:{m['n_pairs']}:{backend}", lambda: _pair_renderer(
        scene, backend, worker.thread_context() if backend == "gl" else None, target, world))
    add = _noise_function(None if m["noise"] is None else Noise(**m["noise"]))
    return [render_pair(r, target, poses[i], world[i], i, settings, m["seed"], add, Path(task["out"]))
            for i in task["pairs"]]


def _noise_seed(seed: int, pair: int, camera: int) -> int:
    return int(np.random.SeedSequence([seed, pair, camera]).generate_state(1)[0])


def _half_size(target) -> float:
    """Half extent (mm) of the target's points plus their features, for pose placement."""
    p = target.true_points()
    extra = float(np.max(target.diameters())) / 2 if isinstance(target, DotGrid) else 0.0
    return float(np.max(np.abs(p[:, :2]))) + extra


def _corner_truth(target, R_world, t_world, cam: Camera) -> dict[str, np.ndarray]:
    """Chessboard/ChArUco corners: their projection and whether it is inside the image."""
    uv, ok = project(target.true_points() @ np.asarray(R_world).T + np.asarray(t_world), cam)
    W, H = cam.size
    inside = ok & (uv[:, 0] >= 1) & (uv[:, 0] <= W - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= H - 2)
    return {"projected": np.where(ok[:, None], uv, np.nan), "visible": inside}


def _pair_fix(path: Path) -> str:
    return (f"delete it and its images ({path.stem}_*.tif) and rerun `glsim calib library` with the library's "
            "settings: the pair is rendered again")


def _read_json(path: Path, what: str, fix: str = "") -> dict:
    """A JSON file's object, or SceneError naming the file and what is wrong with it."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise SceneError(str(path), f"cannot be read ({exc.strerror or exc})", fix or "check the path") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneError(str(path), f"is not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno}; "
                         f"{len(text)} bytes — cut off or edited?)",
                         fix or f"restore the {what}, or make the library again with `glsim calib library`") from None
    if not isinstance(data, dict):
        raise SceneError(str(path), f"holds a JSON {type(data).__name__}, not the {what}", fix or "restore it")
    return data


def _check_pair(pair: dict, path: Path, target, cams) -> None:
    """SceneError naming the pair JSON if a key or a camera's truth is missing or has the wrong length."""
    fix = _pair_fix(path)
    missing = [k for k in PAIR_KEYS if k not in pair]
    if missing:
        raise SceneError(str(path), f"lacks {', '.join(missing)}", fix)
    n = len(target.points())
    need = ("image", "projected", "visible", "complete") + (("centroid",) if isinstance(target, DotGrid) else ())
    for cam in cams:
        c = pair["cameras"].get(cam.name) if isinstance(pair["cameras"], dict) else None
        if not isinstance(c, dict):
            raise SceneError(str(path), f"has no entry for camera {cam.name!r} under cameras", fix)
        missing = [k for k in need if k not in c]
        if missing:
            raise SceneError(str(path), f"cameras.{cam.name} lacks {', '.join(missing)}", fix)
        for key in ("projected", "visible") + (("centroid",) if "centroid" in need else ()):
            if not isinstance(c[key], list) or len(c[key]) != n:
                got = len(c[key]) if isinstance(c[key], list) else type(c[key]).__name__
                raise SceneError(str(path), f"cameras.{cam.name}.{key} has {got} entries, the target has {n} points",
                                 fix)


def load_library(directory) -> Library:
    """Read a library directory (its manifest, cameras, target and every finished pair), checking
    each file: SceneError names the first broken one, what is wrong and what to do."""
    d = Path(directory)
    path = d / "library.json"
    if not path.is_file():
        raise SceneError(str(path), "not found", "give a directory written by `glsim calib library`")
    manifest = _read_json(path, "library.json of a calibration library")
    missing = [k for k in MANIFEST_KEYS if k not in manifest]
    if missing:
        raise SceneError(str(path), f"lacks {', '.join(missing)}" + (" (a library made by an older glsim: format "
                         f"{manifest['format']})" if manifest.get("format", FORMAT_VERSION) != FORMAT_VERSION else ""),
                         "restore it, or make the library again with `glsim calib library`")
    if not isinstance(manifest["cameras"], list) or not manifest["cameras"]:
        raise SceneError(str(path), "cameras: is not a list of cameras", "restore it, or make the library again")
    cams = tuple(read_camera(c, str(path)) for c in manifest["cameras"])
    target = target_from_dict(manifest["target"], str(path)) if isinstance(manifest["target"], dict) else \
        target_from_dict({}, str(path))
    pairs = []
    for p in sorted((d / "pairs").glob("[0-9]*.json")):
        pair = _read_json(p, "pair ground truth", _pair_fix(p))
        _check_pair(pair, p, target, cams)
        pairs.append(pair)
    return Library(d, target, cams, tuple(pairs), manifest)


def image_truth(lib: Library, pair: dict, cam: Camera) -> dict[str, np.ndarray]:
    """A pair's ground truth for one camera as arrays."""
    c = pair["cameras"][cam.name]
    return {k: np.asarray(c[k], float if k != "visible" else bool) for k in ("projected", "centroid", "visible")
            if k in c}
