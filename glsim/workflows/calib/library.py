"""Calibration-image libraries: N stereo pairs of a target in random poses, rendered through the
normal pipeline, with per-pair ground truth and the true rig calibration.

Layout of a library directory::

    library.json          what was made: target, cameras, poses spec, render options, seed
    rig.yaml              the true calibration, OpenCV FileStorage (see :func:`glsim.io.calibfiles.write_rig_yaml`)
    pairs/0000_cam0.tif   images, one per camera (8-bit TIFF for 8-bit cameras)
    pairs/0000.json       the pair's ground truth, written last (a pair is done when it exists)

The paper's Table 8 set-up is :func:`paper_rig`; its names map to OpenCV's as in
docs/calib.md (Kappa 1/2 are k1/k2 on normalized coordinates, not px⁻²).
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from glsim.io import images as io
from glsim.io.calibfiles import opencv_distortion, stereo_extrinsics, write_rig_yaml
from glsim.scene.camera import Camera, Distortion, project, stereo_pose
from glsim.errors import SceneError
from glsim.render import Renderer
from glsim.scene import Render, Scene
from glsim.workflows.calib import poses as posemod
from glsim.workflows.calib.targets import Charuco, Chessboard, Defects, DotGrid, plate_mesh, reference

FORMAT_VERSION = 1
OUTLINE_POINTS = 512   # polygon vertices per dot outline for the true image centroid

# Table 8 of the reference paper: camera 1 and 2 intrinsics, stereo extrinsics (mm, degrees).
PAPER_CAMERAS = ({"fx": 2900.0, "k1": -0.46, "k2": -0.166}, {"fx": 3115.0, "k1": -0.35, "k2": -0.01})
PAPER_PRINCIPAL_POINT = (812.0, 617.0)
PAPER_SIZE = (1624, 1234)
PAPER_STEREO = {"Tx": 144.0, "Ty": -12.8, "Tz": 60.0, "Theta": -1.85, "Phi": -22.8, "Psi": -1.9}

Noise = Callable[[np.ndarray, Camera, int], np.ndarray]


def paper_rig(scale: float = 1.0, bit_depth: int = 8) -> tuple[Camera, Camera]:
    """The Table 8 stereo rig, optionally scaled to ``scale`` × 1624×1234 px.

    Scaling keeps the optics: focal lengths scale by ``scale`` and the principal point keeps
    its place on the sensor (c' = (c + ½)·scale − ½ in pixel-centre coordinates); distortion
    coefficients (on normalized coordinates) are unchanged. The axes converge ≈ 372 mm in
    front of camera 1.
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


# --- ground truth ---------------------------------------------------------------------------

def to_world(R, t, cam1: Camera) -> tuple[np.ndarray, np.ndarray]:
    """A target pose given in camera 1's frame as a target → world pose."""
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


def target_from_dict(d: dict):
    d = dict(d)
    kind = d.pop("type")
    if kind == "DotGrid":
        d["defects"] = Defects(**d["defects"])
        d["markers"] = tuple(tuple(m) for m in d["markers"])
        return DotGrid(**d)
    classes = {"Chessboard": Chessboard, "Charuco": Charuco}
    if kind not in classes:
        raise SceneError("library.json.target.type", f"{kind!r} is unknown", "use DotGrid, Chessboard or Charuco")
    return classes[kind](**d)


def camera_to_dict(cam: Camera) -> dict:
    return dataclasses.asdict(cam)


def camera_from_dict(d: dict) -> Camera:
    d = dict(d)
    d["distortion"] = Distortion(**d["distortion"])
    return Camera(**d)


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


def write_library(rig, target, n_pairs: int, out_dir, seed: int = 0, backend: str | None = None,
                  spec: posemod.PoseSpec = posemod.PoseSpec(), noise: Noise | None = None, ctx=None,
                  progress: Callable[[int, int], None] | None = None) -> Library:
    """Render ``n_pairs`` poses of ``target`` seen by every camera of ``rig`` into ``out_dir``.

    ``rig``: a Scene (its cameras and [render] options are used) or cameras such as
    :func:`paper_rig` (then exact mode, 16 samples per pixel). ``noise(image, camera, seed)``
    returns the noisy float image before quantisation; its seed is distinct per pair and
    camera (the hook for glsim.noise; None = noise-free). Pairs already written (their JSON
    exists and the settings match) are kept, so an interrupted run resumes and a larger
    ``n_pairs`` extends the library. Same seed, same library.
    """
    cams, opts = _render_options(rig)
    out = Path(out_dir)
    half = _half_size(target)
    all_poses = posemod.make_poses(cams, half, n_pairs, spec, seed)
    manifest = {"format": FORMAT_VERSION, "seed": seed, "n_pairs": n_pairs, "target": target_to_dict(target),
                "cameras": [camera_to_dict(c) for c in cams], "poses": dataclasses.asdict(spec),
                "render": dataclasses.asdict(opts), "noise": noise is not None}
    existing = out / "library.json"
    if existing.is_file():
        old = json.loads(existing.read_text())
        settings = lambda m: {k: v for k, v in m.items() if k not in ("seconds_per_pair", "n_pairs")}  # noqa: E731
        if settings(old) != settings(json.loads(json.dumps(manifest))) or n_pairs < old["n_pairs"]:
            raise SceneError(str(existing), "belongs to a library made with other settings",
                             "write to an empty directory, remove the old library, or only add pairs")
        if "seconds_per_pair" in old:
            manifest["seconds_per_pair"] = old["seconds_per_pair"]
    io.write_text(existing, json.dumps(manifest, indent=1))
    if len(cams) == 2:
        write_true_rig(out / "rig.yaml", cams[0], cams[1])
    world = [to_world(p.R, p.t, cams[0]) for p in all_poses]
    todo = [i for i in range(n_pairs) if not (out / "pairs" / f"{pair_name(i)}.json").is_file()]
    scene = Scene(cameras=cams, render=opts)
    seconds = []
    with Renderer(scene, backend, ctx=ctx, mesh=plate_mesh(target, world), reference=reference(target)) as r:
        for n_done, i in enumerate(todo, 1):
            t0 = time.perf_counter()
            p, (Rw, tw) = all_poses[i], world[i]
            record = {"pair": i, "kind": p.kind, "cell": p.cell, "R": p.R, "t": p.t, "rvec": p.rvec.tolist(),
                      "points_world": (target.true_points() @ Rw.T + tw).tolist(), "cameras": {}}
            for k, cam in enumerate(cams):
                image = r.render(cam.name, step=i + 1).image
                if noise is not None:
                    image = noise(image, cam, _noise_seed(seed, i, k))
                name = f"{pair_name(i)}_{cam.name}.tif"
                io.write_image(out / "pairs" / name, image, cam.bit_depth)
                truth = dot_truth(target, Rw, tw, cam) if isinstance(target, DotGrid) else \
                    _corner_truth(target, Rw, tw, cam)
                record["cameras"][cam.name] = {"image": name, **{key: v.tolist() for key, v in truth.items()},
                                               "complete": bool(truth["visible"].all())}
            io.write_text(out / "pairs" / f"{pair_name(i)}.json", json.dumps(record))
            seconds.append(time.perf_counter() - t0)
            if progress:
                progress(n_done, len(todo))
    if seconds:   # the median of this run's pairs
        io.write_text(existing, json.dumps({**manifest, "seconds_per_pair": float(np.median(seconds))}, indent=1))
    return load_library(out)


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


def load_library(directory) -> Library:
    """Read a library directory (its manifest, cameras, target and every finished pair)."""
    d = Path(directory)
    path = d / "library.json"
    if not path.is_file():
        raise SceneError(str(path), "not found", "give a directory written by `glsim calib library`")
    manifest = json.loads(path.read_text())
    cams = tuple(camera_from_dict(c) for c in manifest["cameras"])
    pairs = tuple(json.loads(p.read_text()) for p in sorted((d / "pairs").glob("[0-9]*.json")))
    return Library(d, target_from_dict(manifest["target"]), cams, pairs, manifest)


def image_truth(lib: Library, pair: dict, cam: Camera) -> dict[str, np.ndarray]:
    """A pair's ground truth for one camera as arrays."""
    c = pair["cameras"][cam.name]
    return {k: np.asarray(c[k], float if k != "visible" else bool) for k in c if k not in ("image", "complete")}
