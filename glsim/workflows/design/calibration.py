"""The rig a design measures with: the scene's own cameras, or a stereo calibration of them from a
simulated target library, so that calibration error reaches the planner's result.

A design spec's ``[calibration]`` table::

    [calibration]
    rig = "targets"        # "exact" (default): the scene's own cameras, no calibration error
    pairs = 15             # usable stereo pairs of the target (both cameras see half its points)
    target = "dots"        # dots (9 × 9, markers), chessboard (7 × 10 squares), charuco (7 × 5)
    pitch_mm = "auto"      # dot pitch / square size; auto: the grid spans half the shared field of view
    noise = 2.0            # sensor noise σ, % of the dynamic range; default the scene's own [noise], else 2
    fov = "full"           # target poses over the full shared field of view, or its "centre"
    model = "k1k2p1p2k3"   # distortion terms fitted (glsim calib run --model)
    seed = 0               # the poses' and the noise's seed
    backend = "gl"         # renders the target images; default the scene's [render] backend

:func:`calibration_spec` checks the table (nothing rendered); :func:`calibrated_rig` renders the
library of the scene's first two cameras (``glsim calib library``: exact mode, 16 samples per
pixel, no blur or lighting), calibrates it (``glsim calib run``: bias-corrected) and returns the
estimated cameras. The calibration fixes camera 1 relative to camera 0 only, so the estimated
camera 0 keeps the true camera 0's world pose (the specimen stays where the scene put it) and the
estimated camera 1 is placed by the estimated stereo extrinsics from there.
"""
from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.io import images as io
from glsim.io.cameras import camera_from_dict, camera_to_dict
from glsim.scene import Noise, Render, Scene
from glsim.scene.camera import Camera, Distortion
from glsim.workflows.library.spec import SpecError

RIGS = ("exact", "targets")
TARGETS = ("dots", "chessboard", "charuco")
FOVS = ("full", "centre")
MODELS = ("k1", "k1k2", "k1k2p1p2", "k1k2p1p2k3")      # glsim.workflows.calib.calibrate.MODELS
BACKENDS = ("gl", "cpu")
KEYS = ("rig", "pairs", "target", "pitch_mm", "noise", "fov", "model", "seed", "backend")
DEFAULT_PAIRS = 15
MIN_PAIRS, MAX_PAIRS = 3, 1000      # a stereo calibration needs 3 views; 1000 is the paper's largest study
MAX_NOISE = 50.0                    # % of the dynamic range
TARGET_SHARE = 0.5                  # auto pitch: the points span this share of the shared field of view
NICE = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)   # printed pitches, × a power of ten
REFERENCE_PX_PER_PITCH = 100        # the reference image's floor: 10 px/mm at the paper's 10 mm pitch
FORMAT = 1                          # of result.json; a change recalibrates
SPP = 16                            # samples per pixel, as `glsim calib library`
PARALLEL_DEG = 0.5                  # optical axes closer than this have no convergence point to pose around


@dataclass(frozen=True)
class CalibrationSpec:
    """A checked ``[calibration]`` table. ``noise`` None: the scene's own [noise], else 2 %;
    ``pitch_mm`` None: auto; ``backend`` None: the scene's [render] backend."""
    rig: str = "exact"
    pairs: int = DEFAULT_PAIRS
    target: str = "dots"
    pitch_mm: float | None = None
    noise: float | None = None
    fov: str = "full"
    model: str = "k1k2p1p2k3"
    seed: int = 0
    backend: str | None = None


@dataclass(frozen=True)
class CalibratedRig:
    """The cameras a design measures with and how far they are from the truth.

    ``report``: ``rms_px`` (stereo reprojection RMS), ``epipolar_max_px``, ``pairs`` drawn and
    ``pairs_used``, ``errors`` (estimate − truth: fx1 … k1_1, fx2 … k1_2 in px or unitless as
    calibrate.run names them; camera 1 is ``cam0``), ``T_norm_mm`` |ΔT|, ``rotation_deg``,
    ``pitch_mm``, ``noise`` and ``seconds`` (rendering, detection and calibration, in the run that made
    it); all zero for rig "exact"."""
    rig: str
    cam0: Camera
    cam1: Camera
    report: dict


ERROR_KEYS = tuple(f"{p}{i}" for i in (1, 2) for p in ("fx", "fy", "cx", "cy")) + ("k1_1", "k1_2")


def _fail(key: str, problem: str, fix: str):
    raise SpecError(f"{key}: {problem} — {fix}")


def _int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _choice(table: dict, key: str, where: str, allowed, default):
    value = table.get(key, default)
    if value not in allowed:
        close = difflib.get_close_matches(str(value), allowed, 1) if isinstance(value, str) else []
        _fail(f"{where}.{key}", f"{value!r} is not one of {', '.join(allowed)}",
              (f"did you mean {close[0]!r}? " if close else "") + f"write {key} = \"{allowed[0]}\"")
    return value


def calibration_spec(table: dict, key_prefix: str = "calibration") -> CalibrationSpec:
    """Check a ``[calibration]`` table; SpecError naming the key, the culprit and the fix."""
    if table is None:
        table = {}
    if not isinstance(table, dict):
        _fail(key_prefix, f"expected a table, got {table!r}", f"write [{key_prefix}] with rig = \"exact\" or "
              "rig = \"targets\"")
    for key in table:
        if key not in KEYS:
            close = difflib.get_close_matches(str(key), KEYS, 1)
            _fail(f"{key_prefix}.{key}", "unknown key", (f"did you mean {close[0]!r}? " if close else "")
                  + f"allowed: {', '.join(KEYS)}")
    rig = _choice(table, "rig", key_prefix, RIGS, "exact")
    if rig == "exact":
        extra = sorted(k for k in table if k != "rig")
        if extra:
            _fail(f"{key_prefix}.{extra[0]}", "applies to rig = \"targets\" only, and rig is \"exact\"",
                  f"write rig = \"targets\" to calibrate from a simulated target library, or leave {extra[0]} out")
        return CalibrationSpec()
    pairs = table.get("pairs", DEFAULT_PAIRS)
    if not (_int(pairs) and MIN_PAIRS <= pairs <= MAX_PAIRS):
        _fail(f"{key_prefix}.pairs", f"expected an integer {MIN_PAIRS}…{MAX_PAIRS}, got {pairs!r}",
              f"write pairs = {DEFAULT_PAIRS} (a stereo calibration needs at least {MIN_PAIRS} views)")
    target = _choice(table, "target", key_prefix, TARGETS, "dots")
    pitch = table.get("pitch_mm", "auto")
    if pitch != "auto" and not (_number(pitch) and 0 < pitch <= 1e4):
        _fail(f"{key_prefix}.pitch_mm", f"expected \"auto\" or a number of mm in (0, 10000], got {pitch!r}",
              "write pitch_mm = \"auto\" (the grid spans half the field of view both cameras share) or e.g. 10")
    noise = table.get("noise")
    if noise is not None and not (_number(noise) and 0 <= noise <= MAX_NOISE):
        _fail(f"{key_prefix}.noise", f"expected a σ of 0…{MAX_NOISE:g} % of the dynamic range, got {noise!r}",
              "write noise = 2 (Table 8's sensor), 0 for none, or leave it out for the scene's own [noise]")
    fov = _choice(table, "fov", key_prefix, FOVS, "full")
    model = _choice(table, "model", key_prefix, MODELS[::-1], "k1k2p1p2k3")
    seed = table.get("seed", 0)
    if not (_int(seed) and 0 <= seed < 2 ** 32):
        _fail(f"{key_prefix}.seed", f"expected an integer 0…2³²−1, got {seed!r}", "write seed = 0")
    backend = _choice(table, "backend", key_prefix, BACKENDS, None) if "backend" in table else None
    return CalibrationSpec(rig=rig, pairs=pairs, target=target, pitch_mm=None if pitch == "auto" else float(pitch),
                           noise=None if noise is None else float(noise), fov=fov, model=model, seed=seed,
                           backend=backend)


# --- the target --------------------------------------------------------------------------------

def nice(x: float) -> float:
    """The printed pitch nearest ``x`` (in log scale): 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10ᵏ."""
    k = math.floor(math.log10(x))
    options = [float(f"{m}e{e}") for e in (k - 1, k, k + 1) for m in NICE]   # decimal: 0.12, not 0.12000000000000001
    return min(options, key=lambda v: abs(math.log(v / x)))


def _unit_target(kind: str):
    from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid
    return {"dots": DotGrid(pitch=1.0, dot_diameter=0.5, marker_diameter=0.3, margin=1.0),
            "chessboard": Chessboard(square=1.0, margin=1.0),
            "charuco": Charuco(square=1.0, marker=0.7, margin=1.0)}[kind]


def auto_pitch(cams: tuple[Camera, Camera], kind: str, fov: str = "full") -> float:
    """The pitch (mm) at which the target's points span TARGET_SHARE of the smaller extent of the
    field of view both cameras share at the rig's working distance, rounded to a printed pitch:
    10 mm for the paper's Table 8 rig (the library's default target)."""
    from glsim.workflows.calib.poses import common_fov, rig_frame
    cams = stereo_cameras(cams)
    B, o = rig_frame(cams)
    ext = common_fov(cams, B, o)
    span = float(np.ptp(_unit_target(kind).points()[:, :2], axis=0).max())
    return nice(TARGET_SHARE * min(ext[0] + ext[1], ext[2] + ext[3]) / span)


def make_target(kind: str, pitch: float, px_per_mm: float):
    """The calib library's default target of ``kind`` scaled to ``pitch`` (its sizes in proportion
    to its 10 mm default: dots 0.5, markers 0.3, margin 1 pitch; ChArUco markers 0.7 squares)."""
    from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid
    if kind == "dots":
        return DotGrid(pitch=pitch, dot_diameter=0.5 * pitch, marker_diameter=0.3 * pitch, margin=pitch,
                       px_per_mm=px_per_mm)
    if kind == "chessboard":
        return Chessboard(square=pitch, margin=pitch, px_per_mm=px_per_mm)
    ppm = math.ceil(px_per_mm * pitch - 1e-9) / pitch          # whole reference pixels per square
    return Charuco(square=pitch, marker=0.7 * pitch, margin=pitch, px_per_mm=ppm)


# --- the rig -----------------------------------------------------------------------------------

def stereo_cameras(cams, key: str = "calibration.rig") -> tuple[Camera, Camera]:
    """The first two of ``cams``, checked: they converge and see a region in common where their
    axes meet (the library poses its target there); SpecError naming ``key`` otherwise."""
    cams = tuple(cams)
    if len(cams) < 2:
        _fail(key, f"rig = \"targets\" calibrates a stereo pair, and the scene has {len(cams)} camera",
              "give the scene two cameras, or write rig = \"exact\"")
    a, b = cams[:2]
    axes = [c.rotation.T @ [0.0, 0.0, 1.0] for c in (a, b)]
    angle = math.degrees(math.acos(max(-1.0, min(1.0, float(np.dot(*axes))))))
    if angle < PARALLEL_DEG:
        _fail(key, f"cameras {a.name} and {b.name} look in parallel ({angle:.2g}° apart): the target poses are "
              "placed around the point where their optical axes meet", "converge the cameras (stereo DIC angles are "
              "typically 15–30°), or write rig = \"exact\"")
    from glsim.workflows.calib.poses import common_fov, rig_frame
    B, o = rig_frame((a, b))
    if o[2] <= 0 or min(common_fov((a, b), B, o)) <= 0:
        _fail(key, f"cameras {a.name} and {b.name} see nothing in common where their optical axes meet "
              f"({o[2]:.4g} mm along {a.name}'s axis): the target poses are placed there",
              "point the cameras at the same region of the specimen, or write rig = \"exact\"")
    return a, b


def resolved_noise(spec: CalibrationSpec, scene) -> Noise | None:
    """The calibration images' sensor noise: the spec's σ (0: none), else the scene's own
    [noise] (the same sensors), else Table 8's 2 %."""
    if spec.noise is not None:
        return Noise(sigma=spec.noise) if spec.noise > 0 else None
    own = getattr(scene, "noise", None)
    return own if own is not None else Noise(sigma=2.0)


def _inputs(spec: CalibrationSpec, cams, noise, backend: str) -> dict:
    return {"format": FORMAT, "spec": dataclasses.asdict(spec), "cameras": [camera_to_dict(c) for c in cams],
            "noise": None if noise is None else dataclasses.asdict(noise), "backend": backend}


def inputs_hash(spec: CalibrationSpec, scene) -> str:
    """SHA-256 of what a calibration depends on: the spec, the first two cameras, the resolved
    noise and the backend (the name of its directory in a workdir)."""
    backend = spec.backend or scene.render.backend
    cams = stereo_cameras(scene.cameras) if spec.rig == "targets" else tuple(scene.cameras[:2])
    text = json.dumps(_inputs(spec, cams, resolved_noise(spec, scene), backend), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def estimated_cameras(truth: tuple[Camera, Camera], estimate: dict) -> tuple[Camera, Camera]:
    """Cameras from a calibration's estimate (calibrate.parameters' names): the truth's names,
    sizes and bit depths; camera 0 at the true camera 0's world pose, camera 1 at the estimated
    stereo extrinsics from it (X_cam1 = R·X_cam0 + T)."""
    from glsim.scene.camera import rotation_xyz
    a, b = truth
    R = rotation_xyz(*(estimate[k] for k in ("Theta", "Phi", "Psi")))
    T = np.array([estimate[k] for k in ("Tx", "Ty", "Tz")])

    def cam(true: Camera, i: int, R_: np.ndarray, t_: np.ndarray) -> Camera:
        D = [estimate[f"{n}_{i}"] for n in ("k1", "k2", "p1", "p2", "k3")]
        return Camera(name=true.name, size=true.size, fx=estimate[f"fx{i}"], fy=estimate[f"fy{i}"],
                      cx=estimate[f"cx{i}"], cy=estimate[f"cy{i}"], distortion=Distortion.from_opencv(D),
                      R=R_, t=t_, bit_depth=true.bit_depth)
    return cam(a, 1, a.rotation, a.translation), cam(b, 2, R @ a.rotation, R @ a.translation + T)


def exact_rig(scene) -> CalibratedRig:
    """The scene's own first two cameras (the first twice where it has one), with zero errors."""
    cams = tuple(scene.cameras)
    report = {"rms_px": 0.0, "epipolar_max_px": 0.0, "pairs": 0, "pairs_used": 0,
              "errors": {k: 0.0 for k in ERROR_KEYS}, "T_norm_mm": 0.0, "rotation_deg": 0.0,
              "pitch_mm": None, "noise": None, "seconds": 0.0}
    return CalibratedRig("exact", cams[0], cams[1] if len(cams) > 1 else cams[0], report)


def calibrated_rig(spec: CalibrationSpec, scene, workdir, ctx=None, progress=None) -> CalibratedRig:
    """The rig ``spec`` asks for. For rig "targets": the library of the scene's first two cameras
    and its calibration in ``workdir/calibration-<inputs hash>/`` (nothing written elsewhere);
    a finished one of the same inputs is read back, an interrupted one resumed (the library
    keeps its finished pairs). Same inputs and seed, same numbers. ``ctx``: a GL context to
    render in (as write_library's)."""
    if spec.rig == "exact":
        return exact_rig(scene)
    t0 = time.perf_counter()
    cams = stereo_cameras(scene.cameras)
    backend = spec.backend or scene.render.backend
    noise = resolved_noise(spec, scene)
    digest = inputs_hash(spec, scene)
    out = Path(workdir) / f"calibration-{digest[:16]}"
    result = out / "result.json"
    if result.is_file():
        done = _read_result(result, digest)
        return CalibratedRig("targets", camera_from_dict(done["cameras"][0]), camera_from_dict(done["cameras"][1]),
                             done["report"])
    from glsim.workflows.calib import calibrate as cal
    from glsim.workflows.calib import library as libmod
    from glsim.workflows.calib.poses import PoseSpec

    poses = PoseSpec(fov=spec.fov)
    pitch = spec.pitch_mm or auto_pitch(cams, spec.target, spec.fov)
    target = make_target(spec.target, pitch, libmod.auto_px_per_mm(cams, poses, floor=REFERENCE_PX_PER_PITCH / pitch))
    rig = Scene(cameras=cams, render=Render(backend=backend, mode="exact", samples_per_pixel=SPP))
    lib, _ = cal.write_usable_library(rig, target, spec.pairs, out / "library", progress=progress, seed=spec.seed,
                                      backend=backend, spec=poses, noise=noise, ctx=ctx)
    rep = cal.run(lib.directory, out / "calibration", model=spec.model)   # (OpenCV on one thread: the same bits)
    est = estimated_cameras(cams, rep["estimate"])
    report = {"rms_px": rep["rms"], "epipolar_max_px": rep["epipolar_max_px"], "pairs": rep["pairs"],
              "pairs_used": rep["pairs_used"], "errors": {k: rep["errors"][k] for k in ERROR_KEYS},
              "T_norm_mm": rep["errors"]["T_norm"], "rotation_deg": rep["errors"]["rotation_deg"],
              "pitch_mm": pitch, "noise": None if noise is None else dataclasses.asdict(noise),
              "seconds": time.perf_counter() - t0}
    report = json.loads(json.dumps(report))
    io.write_text(result, json.dumps({"format": FORMAT, "inputs_sha256": digest,
                                      "cameras": [camera_to_dict(c) for c in est], "report": report}, indent=1))
    return CalibratedRig("targets", *est, report)


def _read_result(path: Path, digest: str) -> dict:
    """A finished calibration's result.json, checked; SceneError naming it otherwise."""
    fix = f"delete {path.parent} and run again: the calibration is made anew"
    try:
        done = json.loads(path.read_text())
        ok = done["format"] == FORMAT and done["inputs_sha256"] == digest
        cams = [camera_from_dict(c) for c in done["cameras"]]      # (a SceneError is a ValueError)
        if len(cams) != 2 or not isinstance(done["report"], dict):
            raise ValueError("not two cameras and a report")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SceneError(str(path), f"is not a finished calibration ({type(exc).__name__}: {exc})", fix) from None
    if not ok:
        raise SceneError(str(path), "was made from other inputs than its directory's name says", fix)
    return done
