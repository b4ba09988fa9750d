"""Stereo calibration of a library: detection in every pair, cv2.calibrateCamera per camera,
then cv2.stereoCalibrate refining everything together (a full bundle: intrinsics, distortion,
extrinsics and every target pose), and the comparison with the true rig.

Outputs of :func:`run` (in ``out_dir``): ``calibration.yaml`` (OpenCV FileStorage, same keys
as the library's rig.yaml), ``report.json`` (RMS, estimates, errors against the truth,
detection errors), ``residuals.csv`` (one line per pair and camera) and ``epipolar.png`` (the
epipolar-distance map over camera 1's field of view, like the paper's Fig. 14).
"""
from __future__ import annotations

import contextlib
import csv
import io as _io
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.io import images as io
from glsim.io.atomic import atomic_paths
from glsim.io.calibfiles import euler_xyz, write_rig_yaml
from glsim.io.hashes import sha256_file
from glsim.scene.camera import Camera, distort, normalized_to_pixel, pixel_rays, project
from glsim.errors import SceneError
from glsim.workflows.calib import library as libmod
from glsim.workflows.calib.detect import VERSION as DETECTOR_VERSION, default_method, detect_target
from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid
from glsim.workflows.calib.poses import rig_frame

MODELS = {  # distortion terms estimated → OpenCV flags
    "k1": ("CALIB_FIX_K2", "CALIB_FIX_K3", "CALIB_ZERO_TANGENT_DIST"),
    "k1k2": ("CALIB_FIX_K3", "CALIB_ZERO_TANGENT_DIST"),
    "k1k2p1p2": ("CALIB_FIX_K3",),
    "k1k2p1p2k3": (),
}
CRITERIA = (3, 200, 1e-12)   # cv2.TERM_CRITERIA_COUNT | EPS, max iterations, epsilon
BIAS_OUTLINE_POINTS = 128    # polygon vertices per dot in the perspective-bias correction


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """A stereo calibration in OpenCV's terms: K (3×3 px), D (k1 k2 p1 p2 k3), camera 1
    relative to camera 0 X_cam1 = R·X_cam0 + T (mm), E, F; ``rms`` is stereoCalibrate's
    RMS reprojection error over both cameras (px), ``rms1``/``rms2`` calibrateCamera's;
    ``per_view`` (n, 2) RMS per pair and camera; ``rvecs``/``tvecs`` (n, 3) each pair's
    target pose in camera 0 (Rodrigues, mm); ``pairs`` the library pairs used."""
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    E: np.ndarray
    F: np.ndarray
    rms: float
    rms1: float
    rms2: float
    per_view: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    pairs: tuple[int, ...]
    image_size: tuple[int, int]


def model_flags(model: str) -> int:
    import cv2
    if model not in MODELS:
        raise SceneError("model", f"{model!r} is not one of {list(MODELS)}", "choose the distortion terms to fit")
    flags = cv2.CALIB_FIX_SKEW if hasattr(cv2, "CALIB_FIX_SKEW") else 0
    for name in MODELS[model]:
        flags |= getattr(cv2, name)
    return flags


@contextlib.contextmanager
def one_opencv_thread():
    """OpenCV's solvers on one thread: with several, stereoCalibrate's sums come out in another order
    from run to run (estimates differ by ~1e-11 relative), and the same library must give the same
    calibration to the bit; one thread costs ~0.1 s a calibration here."""
    import cv2
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def calibrate(object_points: list[np.ndarray], points1: list[np.ndarray], points2: list[np.ndarray],
              image_size: tuple[int, int], model: str = "k1k2p1p2k3", pairs=None) -> StereoCalibration:
    """Calibrate from matched views: ``object_points[i]`` (n_i, 3) mm and their images in
    camera 0 and 1 (n_i, 2) px. Each camera first alone, then both together."""
    import cv2
    if len(object_points) < 3:
        raise SceneError("pairs", f"only {len(object_points)} usable pairs", "a calibration needs at least 3")
    flags = model_flags(model)
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    im1 = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in points1]
    im2 = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in points2]
    with one_opencv_thread():
        rms1, K1, D1, *_ = cv2.calibrateCamera(obj, im1, image_size, None, None, flags=flags, criteria=CRITERIA)
        rms2, K2, D2, *_ = cv2.calibrateCamera(obj, im2, image_size, None, None, flags=flags, criteria=CRITERIA)
        rms, K1, D1, K2, D2, R, T, E, F, rvecs, tvecs, per_view = cv2.stereoCalibrateExtended(
            obj, im1, im2, K1, D1, K2, D2, image_size, np.eye(3), np.zeros((3, 1)),
            flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=CRITERIA)
    return StereoCalibration(K1=K1, D1=D1.ravel(), K2=K2, D2=D2.ravel(), R=R, T=T.ravel(), E=E, F=F,
                             rms=float(rms), rms1=float(rms1), rms2=float(rms2), per_view=np.asarray(per_view),
                             rvecs=np.asarray(rvecs).reshape(-1, 3), tvecs=np.asarray(tvecs).reshape(-1, 3),
                             pairs=tuple(range(len(obj)) if pairs is None else pairs), image_size=tuple(image_size))


def write_yaml(path, c: StereoCalibration, atomic: bool = True) -> Path:
    """The calibration as OpenCV YAML: :func:`~glsim.io.calibfiles.write_rig_yaml`'s keys plus E, F and rms
    (``atomic`` False: straight to ``path``, a temporary the caller renames)."""
    return write_rig_yaml(path, c.K1, c.D1, c.K2, c.D2, c.R, c.T, c.image_size, atomic=atomic, E=c.E, F=c.F,
                          rms=c.rms)


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """The angle (deg) of the rotation Ra·Rbᵀ."""
    c = (np.trace(np.asarray(Ra) @ np.asarray(Rb).T) - 1) / 2
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def parameters(K1, D1, K2, D2, R, T) -> dict[str, float]:
    """Flat named parameters (paper/MatchID style): fx1 … k3_1, fx2 … k3_2, Tx Ty Tz (mm),
    Theta Phi Psi (deg)."""
    out = {}
    for i, (K, D) in enumerate(((K1, D1), (K2, D2)), 1):
        D = np.pad(np.ravel(D), (0, 5))[:5]
        out.update({f"fx{i}": K[0, 0], f"fy{i}": K[1, 1], f"cx{i}": K[0, 2], f"cy{i}": K[1, 2],
                    f"k1_{i}": D[0], f"k2_{i}": D[1], f"p1_{i}": D[2], f"p2_{i}": D[3], f"k3_{i}": D[4]})
    out.update(dict(zip(("Tx", "Ty", "Tz"), np.ravel(T))))
    out.update(dict(zip(("Theta", "Phi", "Psi"), euler_xyz(R))))
    return {k: float(v) for k, v in out.items()}


def true_parameters(cam1: Camera, cam2: Camera) -> dict[str, float]:
    R, T = libmod.stereo_extrinsics(cam1, cam2)
    return parameters(cam1.K, cam1.distortion.coeffs, cam2.K, cam2.distortion.coeffs, R, T)


def errors(c: StereoCalibration, cam1: Camera, cam2: Camera) -> dict[str, float]:
    """Estimate − truth for every parameter, plus |T error| (mm) and the rotation error (deg)."""
    est = parameters(c.K1, c.D1, c.K2, c.D2, c.R, c.T)
    true = true_parameters(cam1, cam2)
    out = {k: est[k] - true[k] for k in est}
    R, T = libmod.stereo_extrinsics(cam1, cam2)
    out["T_norm"] = float(np.linalg.norm(c.T - T))
    out["rotation_deg"] = rotation_angle(c.R, R)
    return out


def undistort_px(uv: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Distorted pixels (n, 2) → undistorted pixels of the same K (OpenCV, iterated to 1e-12)."""
    import cv2
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    return cv2.undistortPoints(np.asarray(uv, np.float64).reshape(-1, 1, 2), K, D, P=K,
                               criteria=crit).reshape(-1, 2)


def epipolar_distance(c: StereoCalibration, uv1: np.ndarray, uv2: np.ndarray) -> np.ndarray:
    """Distance (px, in camera 1's undistorted image) of each ``uv2`` from the epipolar line
    of ``uv1`` under calibration ``c`` (both distorted pixel positions)."""
    p1 = np.c_[undistort_px(uv1, c.K1, c.D1), np.ones(len(uv1))]
    p2 = np.c_[undistort_px(uv2, c.K2, c.D2), np.ones(len(uv2))]
    lines = p1 @ np.asarray(c.F).T
    return np.abs(np.sum(lines * p2, axis=1)) / np.hypot(lines[:, 0], lines[:, 1])


def epipolar_map(c: StereoCalibration, cam1: Camera, cam2: Camera, step: int = 8):
    """The epipolar distance of the truly corresponding points of the rig's working plane
    (through the convergence point, facing the rig) over camera 0's image, every ``step`` px:
    ``(u, v, d)`` with d (px) NaN where camera 1 does not see the point."""
    W, H = cam1.size
    u, v = np.meshgrid(np.arange(0, W, step, dtype=float), np.arange(0, H, step, dtype=float))
    uv1 = np.stack([u.ravel(), v.ravel()], axis=1)
    d, ok = pixel_rays(uv1, cam1)                            # camera 0 frame
    B, o = rig_frame((cam1, cam2))
    n = B[:, 2]
    X1 = d * ((o @ n) / (d @ n))[:, None]
    Xw = (X1 - cam1.translation) @ cam1.rotation             # camera 0 → world
    uv2, ok2 = project(Xw, cam2)
    seen = ok & ok2 & (uv2[:, 0] >= 0) & (uv2[:, 0] <= cam2.width - 1) & (uv2[:, 1] >= 0) & \
        (uv2[:, 1] <= cam2.height - 1)
    dist = np.full(len(uv1), np.nan)
    dist[seen] = epipolar_distance(c, uv1[seen], uv2[seen])
    return u, v, dist.reshape(u.shape)


def pyplot():
    """matplotlib.pyplot on the Agg backend, or a SceneError saying how to install it."""
    try:
        import matplotlib
    except ModuleNotFoundError:
        raise SceneError("matplotlib", "is not installed; the calibration figures need it",
                         "pip install 'glsim[calib]' (or matplotlib)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def write_epipolar_png(path, u, v, d, title: str = "", atomic: bool = True) -> Path:
    """The epipolar-distance map as a colour image with a scale (matplotlib); ``atomic`` False:
    straight to ``path``, a temporary the caller renames."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 5.0), dpi=120)
    step = u[0, 1] - u[0, 0] if u.shape[1] > 1 else 1
    im = ax.imshow(d, extent=(u.min() - step / 2, u.max() + step / 2, v.max() + step / 2, v.min() - step / 2),
                   cmap="viridis")
    fig.colorbar(im, ax=ax, label="epipolar distance [px]")
    ax.set_xlabel("u [px] (camera 0)")
    ax.set_ylabel("v [px]")
    ax.set_title(title or f"max {np.nanmax(d):.3g} px")
    path = Path(path)
    with contextlib.nullcontext(path) if not atomic else io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
    return path


# --- a library end to end ----------------------------------------------------------------------

def supported(lib: libmod.Library) -> None:
    """SceneError unless ``calib run``/``study`` can detect the library's target."""
    if not isinstance(lib.target, (DotGrid, Chessboard, Charuco)):
        raise SceneError(str(lib.directory / "library.json"),
                         f"holds a {type(lib.target).__name__} target, which cannot be detected",
                         "make a DotGrid, Chessboard or Charuco library")
    t = lib.target
    if isinstance(t, Chessboard) and (t.rows + t.cols) % 2 == 0:
        raise SceneError(str(lib.directory / "library.json"),
                         f"holds a {t.rows} × {t.cols} chessboard, which looks the same after a half turn: its corners "
                         "cannot be numbered as the truth's", "use a board with rows + cols odd (e.g. 7 × 10 squares), "
                         "or a ChArUco board")


def cache_path(lib: libmod.Library, min_points: int, method: str | None = None) -> Path:
    method = method or default_method(lib.target)
    return lib.directory / f"detections_v{DETECTOR_VERSION}_{method}_min{min_points}.npz"


def image_checksums(lib: libmod.Library, pair: dict) -> list[str]:
    """SHA-256 of each camera's image of ``pair``; SceneError naming an image that is missing, or
    that differs from the checksum its pair JSON recorded when it was rendered."""
    out = []
    for cam in lib.cameras:
        path = lib.image_path(pair, cam)
        json_path = lib.directory / "pairs" / f"{libmod.pair_name(pair['pair'])}.json"
        if not path.is_file():
            raise SceneError(str(path), "is missing (its pair's ground truth and any detection cache cannot stand in "
                             "for it)", f"restore it, or {libmod._pair_fix(json_path)}")
        sha = sha256_file(path)
        recorded = pair["cameras"][cam.name].get("sha256")
        if recorded is not None and recorded != sha:
            raise SceneError(str(path), f"differs from the image {json_path.name} recorded when it was rendered "
                             "(SHA-256 mismatch: cut off, overwritten or edited)",
                             f"restore it, or {libmod._pair_fix(json_path)}")
        out.append(sha)
    return out


def detect_library(lib: libmod.Library, min_points: int, processes: int = 1, progress=None,
                   method: str | None = None) -> dict:
    """Detections of every pair: {pair index: (points of camera 0, of camera 1, …)}, each (N, 2)
    px with NaN rows where a dot was lost, or None where a camera's grid was not found.

    ``method``: the dot estimator (dotcentres.METHODS; default the model fit); chessboards and
    ChArUco boards are found by OpenCV's detectors (boards.detect_chessboard/detect_charuco).
    Cached in ``detections_v{DETECTOR_VERSION}_{method}_min{min_points}.npz`` in the library,
    keyed by the SHA-256 of each pair's images: a pair whose images changed is detected again,
    a missing or damaged image is named (SceneError), never passed over from the cache. New
    pairs are added to the cache; delete it to detect again."""
    supported(lib)
    method = method or default_method(lib.target)
    cache = cache_path(lib, min_points, method)
    done, keys, why = _read_cache(cache)
    sums = {p["pair"]: image_checksums(lib, p) for p in lib.pairs}
    done = {k: v for k, v in done.items() if k in sums and keys.get(k) == sums[k] and k in why}
    target = libmod.target_to_dict(lib.target)
    jobs = [(p["pair"], [str(lib.image_path(p, c)) for c in lib.cameras], [c.bit_depth for c in lib.cameras],
             [c.size for c in lib.cameras], target, min_points, method) for p in lib.pairs if p["pair"] not in done]
    if jobs:
        if processes > 1:
            import multiprocessing as mp
            with mp.get_context("spawn").Pool(processes) as pool:
                results = _collect(pool.imap_unordered(_detect_job, jobs, chunksize=4), len(jobs), progress)
        else:
            results = _collect(map(_detect_job, jobs), len(jobs), progress)
        for index, r, reasons in results:
            if reasons is None:                 # (file, problem, fix) from the worker
                raise SceneError(*r)
            done[index], why[index] = r, reasons
        arrays = {f"p{k}": v for k, v in done.items()}
        arrays.update({f"s{k}": np.array(sums[k]) for k in done})
        arrays.update({f"r{k}": np.array(why[k]) for k in done})
        with io.atomic_path(cache) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
    return {k: tuple(None if np.all(np.isnan(v[c])) else v[c] for c in range(len(lib.cameras)))
            for k, v in done.items() if k in sums}


def _read_cache(cache: Path) -> tuple[dict, dict, dict]:
    """(points, image checksums, reasons) per pair from a detection cache; empty if unreadable."""
    if not cache.is_file():
        return {}, {}, {}
    try:
        with np.load(cache) as z:
            return ({int(k[1:]): z[k] for k in z.files if k.startswith("p")},
                    {int(k[1:]): [str(x) for x in z[k]] for k in z.files if k.startswith("s")},
                    {int(k[1:]): [str(x) for x in z[k]] for k in z.files if k.startswith("r")})
    except Exception:                           # an unreadable cache is rebuilt, not trusted
        return {}, {}, {}


def skipped_views(lib: libmod.Library, min_points: int, method: str | None = None) -> dict:
    """Why each view of the detected library was not used: {(pair, camera name): reason} from
    its detection cache (:func:`detect_library` first)."""
    _, _, why = _read_cache(cache_path(lib, min_points, method))
    return {(i, cam.name): r[c] for i, r in why.items() for c, cam in enumerate(lib.cameras) if r[c]}


def _collect(results, total: int, progress) -> list:
    out = []
    for k, r in enumerate(results, 1):
        out.append(r)
        if progress:
            progress(k, total)
    return out


def _read_view(path: str, bits: int, size) -> np.ndarray:
    """A library image, or SceneError naming it (unreadable, or not the camera's size)."""
    json_path = Path(path).parent / f"{Path(path).name.split('_')[0]}.json"
    fix = f"restore it, or {libmod._pair_fix(json_path)}"
    try:
        image = io.read_image(path)
    except FileNotFoundError:
        raise SceneError(path, "is missing", fix) from None
    except Exception as exc:
        raise SceneError(path, f"cannot be read as an image ({type(exc).__name__}: {exc})", fix) from None
    W, H = size
    if image.shape != (H, W):
        raise SceneError(path, f"is {image.shape[1]}×{image.shape[0]} px, the camera's images are {W}×{H}", fix)
    return image


def _detect_job(job) -> tuple:
    """One pair: (index, (cameras, N, 2) points, all NaN for a camera that found nothing, the
    reason per camera ("" where found)), or (index, (file, problem, fix), None) for a bad image
    (SceneErrors do not cross process pools)."""
    index, paths, bits, sizes, target, min_points, method = job
    target = libmod.target_from_dict(target)
    try:
        dets = [detect_target(_read_view(p, b, s), target, b, min_points, method, explain=True)
                for p, b, s in zip(paths, bits, sizes)]
    except SceneError as exc:
        text = str(exc)
        key, _, rest = text.partition(": ")
        problem, _, fix = rest.partition(" — ")
        return index, (key, problem, fix), None
    n = len(target.points())
    return (index, np.stack([d.points if d is not None else np.full((n, 2), np.nan) for d, _ in dets]),
            [why for _, why in dets])


def usable(detections: dict, pairs, min_points: int):
    """``(indices, object-point masks)`` of the pairs both cameras detected with ≥ min_points
    common dots."""
    out = []
    for i in pairs:
        if i not in detections:
            raise SceneError("pairs", f"pair {i} has no detection", "detect the library first (detect_library)")
        d1, d2 = detections[i][:2]
        if d1 is None or d2 is None:
            continue
        mask = ~np.isnan(d1[:, 0]) & ~np.isnan(d2[:, 0])
        if mask.sum() >= min_points:
            out.append((i, mask))
    return out


def default_min_points(target) -> int:
    """Points (dots, corners) both views of a pair need by default: half the target's."""
    return (len(target.points()) + 1) // 2


def write_usable_library(rig, target, n_usable: int, out_dir, max_pairs: int | None = None,
                         min_points: int | None = None, processes: int = 1, progress=None,
                         **options) -> tuple[libmod.Library, list[int]]:
    """A library with at least ``n_usable`` pairs that :func:`run` can use (both cameras detect
    ≥ ``min_points`` common dots): draws pairs with :func:`~library.write_library` (``options``
    go to it), detects them (cached for ``run``), and draws more until enough are usable or
    ``max_pairs`` (default 4 × n_usable) are drawn; then raises SceneError saying how many are.
    Returns the library and its usable pairs. Libraries of other than 2 cameras are not counted."""
    if n_usable < 1:
        raise SceneError("pairs", f"must be ≥ 1, got {n_usable}", "give the number of usable pairs wanted")
    max_pairs = max(max_pairs or 4 * n_usable, n_usable)
    n = n_usable
    manifest = Path(out_dir) / "library.json"
    if manifest.is_file():                # an existing library is extended, never shrunk
        try:
            n = max(n, int(json.loads(manifest.read_text())["n_pairs"]))
        except (ValueError, KeyError, TypeError):
            pass
    while True:
        lib = libmod.write_library(rig, target, n, out_dir, progress=progress, **options)
        if len(lib.cameras) != 2:
            return lib, [p["pair"] for p in lib.pairs]
        mp = min_points or default_min_points(lib.target)
        dets = detect_library(lib, mp, processes)
        good = [i for i, _ in usable(dets, sorted(dets), mp)]
        if len(good) >= n_usable or n >= max_pairs:
            break
        rate = max(len(good), 1) / n       # draw as many more as this rate says are needed, and one
        n = min(max_pairs, max(n + 1, math.ceil(n_usable / rate) + 1))
    if len(good) < n_usable:
        raise SceneError("pairs", f"only {len(good)} of the {n} pairs drawn are usable (both cameras detect "
                         f"≥ {mp} common dots), {n_usable} were asked for; the library in {out_dir} keeps them",
                         "raise --max-pairs, ask for fewer pairs, or place the target nearer the centre "
                         "(--fov centre)")
    return lib, good


def centroid_bias(target, R, t, K, D, points: np.ndarray) -> np.ndarray:
    """Image centroid − projected centre (n, 2) px of the nominal dots ``points`` (indices)
    of ``target`` in the pose X_cam = R·X + t through camera (K, D) — the perspective bias.
    The outlines are BIAS_OUTLINE_POINTS-gons: 2e-5 px from the limit for a 35° tilt at full
    size (the ground truth uses 512). OpenCV's model in numpy (4× faster than projectPoints)."""
    a = np.linspace(0.0, 2 * np.pi, BIAS_OUTLINE_POINTS, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a), 0 * a], axis=1)
    centres = target.points()[points]
    outline = centres[:, None] + target.diameters()[points, None, None] / 2 * ring
    k = np.pad(np.ravel(D), (0, 12))[:12]
    intr = (K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])

    def proj(X):
        Xc = X @ np.asarray(R).T + t
        return normalized_to_pixel(distort(Xc[..., :2] / Xc[..., 2:], k), intr)
    return libmod.polygon_centroid(proj(outline)) - proj(centres)


def calibrate_pairs(lib: libmod.Library, detections: dict, pairs, model: str, min_points: int,
                    bias_iterations: int = 0) -> StereoCalibration:
    """Calibrate from the chosen library pairs (those with too few dots are left out).

    ``bias_iterations`` > 0 corrects the perspective bias of dot centroids (the centroid of
    a dot's image is not the image of its centre): the bias of every dot is predicted from
    the current calibration and the target's nominal geometry, subtracted from the
    detections, and the calibration repeated (Heikkilä 2000)."""
    import cv2
    obj = lib.target.points()
    use = usable(detections, pairs, min_points)
    idx = [np.flatnonzero(m) for _, m in use]
    pts = [[detections[i][c][m] for i, m in use] for c in (0, 1)]
    c = calibrate([obj[k] for k in idx], *pts, lib.cameras[0].size, model, [i for i, _ in use])
    for _ in range(bias_iterations if isinstance(lib.target, DotGrid) else 0):   # corners have no such bias
        corrected = [[], []]
        for v, k in enumerate(idx):
            R1 = cv2.Rodrigues(c.rvecs[v])[0]
            poses = ((R1, c.tvecs[v], c.K1, c.D1), (c.R @ R1, c.R @ c.tvecs[v] + c.T, c.K2, c.D2))
            for cam, (R, t, K, D) in enumerate(poses):
                corrected[cam].append(pts[cam][v] - centroid_bias(lib.target, R, t, K, D, k))
        c = calibrate([obj[k] for k in idx], *corrected, lib.cameras[0].size, model, c.pairs)
    return c


def detection_errors(lib: libmod.Library, detections: dict) -> dict:
    """Detected − true image position of every dot found, against the projected dot centre
    and against the true centroid of its image: mean |e|, RMS, max and mean vector (px)."""
    e = {"projected": [], "centroid": []} if isinstance(lib.target, DotGrid) else {"projected": []}
    for pair in lib.pairs:
        for c, cam in enumerate(lib.cameras):
            pts = detections[pair["pair"]][c]
            if pts is None:
                continue
            truth = libmod.image_truth(lib, pair, cam)
            for k in e:
                diff = pts - truth[k]
                e[k].append(diff[~np.isnan(diff[:, 0])])
    out = {}
    for k, v in e.items():
        v = np.concatenate(v) if v else np.zeros((0, 2))
        r = np.linalg.norm(v, axis=1)
        out[k] = {"n": len(v), "mean": float(r.mean()) if len(r) else math.nan,
                  "rms": float(np.sqrt((r ** 2).mean())) if len(r) else math.nan,
                  "max": float(r.max()) if len(r) else math.nan, "bias": v.mean(0).tolist() if len(v) else []}
    return out


def run(library_dir, out_dir=None, model: str = "k1k2p1p2k3", min_points: int | None = None,
        bias_iterations: int = 1, processes: int = 1, progress=None) -> dict:
    """Detect, calibrate and report a whole library (see the module text); returns the report.

    ``min_points``: dots both views of a pair need (default half the target's);
    ``bias_iterations``: perspective-bias corrections (see :func:`calibrate_pairs`)."""
    t0 = time.perf_counter()
    lib = libmod.load_library(library_dir)
    if len(lib.cameras) != 2:
        raise SceneError(str(lib.directory / "library.json"), f"the library has {len(lib.cameras)} cameras",
                         "stereo calibration needs 2")
    supported(lib)
    min_points = min_points or default_min_points(lib.target)
    out = Path(out_dir) if out_dir else lib.directory / "calibration"
    dets = detect_library(lib, min_points, processes, progress)
    c = calibrate_pairs(lib, dets, sorted(dets), model, min_points, bias_iterations)
    cam1, cam2 = lib.cameras
    u, v, d = epipolar_map(c, cam1, cam2)
    report = {"library": str(lib.directory), "model": model, "min_points": min_points,
              "bias_iterations": bias_iterations,
              "pairs": len(lib.pairs), "pairs_used": len(c.pairs),
              "rms": c.rms, "rms_cam1": c.rms1, "rms_cam2": c.rms2,
              "estimate": parameters(c.K1, c.D1, c.K2, c.D2, c.R, c.T),
              "truth": true_parameters(cam1, cam2), "errors": errors(c, cam1, cam2),
              "epipolar_max_px": float(np.nanmax(d)), "detection": detection_errors(lib, dets),
              "seconds": time.perf_counter() - t0}
    skipped = skipped_views(lib, min_points)
    report["views_skipped"] = [{"pair": i, "camera": cam, "reason": r} for (i, cam), r in sorted(skipped.items())]
    for i in sorted(dets):                      # pairs with both views but too few common points
        d1, d2 = dets[i][:2]
        if d1 is not None and d2 is not None and i not in c.pairs:
            common = int((~np.isnan(d1[:, 0]) & ~np.isnan(d2[:, 0])).sum())
            for cam in lib.cameras:
                skipped[(i, cam.name)] = f"the pair's cameras share {common} points, {min_points} needed"
    report["views_skipped"] = [{"pair": i, "camera": cam, "reason": r} for (i, cam), r in sorted(skipped.items())]
    residuals = _residuals_csv(lib, dets, c, skipped)
    # every output under a temporary name first, then all renamed (report.json, the mark of a
    # finished calibration, last): an error or an interrupt leaves the directory as it was
    names = ("calibration.yaml", "epipolar.png", "residuals.csv", "report.json")
    with atomic_paths([out / n for n in names]) as (t_yaml, t_png, t_csv, t_report):
        write_yaml(t_yaml, c, atomic=False)
        write_epipolar_png(t_png, u, v, d, f"epipolar distance, max {np.nanmax(d):.3g} px", atomic=False)
        Path(t_csv).write_text(residuals)
        Path(t_report).write_text(json.dumps(report, indent=1))
    return report


def _residuals_csv(lib: libmod.Library, dets: dict, c: StereoCalibration, skipped: dict | None = None) -> str:
    """pair, kind, camera, dots found, reprojection RMS (px), mean detection error against the
    true centroid and the projected centre (px), and why a view was skipped."""
    skipped = skipped or {}
    buf = _io.StringIO()
    w = csv.writer(buf)
    w.writerow(["pair", "kind", "camera", "used", "dots", "reprojection_rms_px", "det_err_centroid_px",
                "det_err_projected_px", "skipped"])
    rms = {i: c.per_view[k] for k, i in enumerate(c.pairs)}
    for pair in lib.pairs:
        i = pair["pair"]
        for ci, cam in enumerate(lib.cameras):
            pts = dets[i][ci]
            truth = libmod.image_truth(lib, pair, cam)
            ok = ~np.isnan(pts[:, 0]) if pts is not None else np.zeros(len(lib.target.points()), bool)
            err = {k: float(np.linalg.norm(pts[ok] - truth[k][ok], axis=1).mean()) if ok.any() and k in truth else ""
                   for k in ("centroid", "projected")}
            w.writerow([i, pair["kind"], cam.name, int(i in rms), int(ok.sum()),
                        f"{rms[i][ci]:.6f}" if i in rms else "", err["centroid"], err["projected"],
                        skipped.get((i, cam.name), "")])
    return buf.getvalue()
