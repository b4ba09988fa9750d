"""Calibration files: a stereo rig written in the conventions DIC packages read.

OpenCV FileStorage YAML (:func:`write_rig_yaml`, :func:`read_rig_yaml`) and pyvale's
``Calib`` fields (:func:`pyvale_calibration`). Every writer takes the world→camera poses of
:class:`~glsim.scene.camera.Camera` (OpenCV axes, mm) and states the stereo extrinsics as
camera 2 relative to camera 1: X_cam2 = R·X_cam1 + T, R = Rz(Psi)·Ry(Phi)·Rx(Theta)
(:func:`euler_xyz` gives Theta, Phi, Psi in degrees, as MatchID and pyvale name them).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError, SceneError
from glsim.io import images as io
from glsim.scene.camera import Camera


def euler_xyz(R) -> np.ndarray:
    """(theta, phi, psi) in degrees with R = Rz(psi)·Ry(phi)·Rx(theta), the inverse of
    :func:`glsim.camera.rotation_xyz` (phi in (−90°, 90°))."""
    R = np.asarray(R, dtype=np.float64)
    theta = math.atan2(R[2, 1], R[2, 2])
    phi = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    psi = math.atan2(R[1, 0], R[0, 0])
    return np.degrees([theta, phi, psi])


def pyvale_intrinsics(cam: Camera) -> dict:
    """``pyvale.calib.CamIntrinsics`` fields (px): OpenCV's model with [k1, k2, p1, p2, k3]."""
    k = cam.distortion.coeffs
    if np.any(k[5:]):
        raise GlsimError(f"camera {cam.name}: pyvale models only k1, k2, p1, p2, k3; "
                         f"k4…k6 and s1…s4 must be 0, got {k[5:].tolist()}")
    return {"fx": cam.fx, "fy": cam.fy, "fs": cam.skew, "cx": cam.cx, "cy": cam.cy,
            "distortion": k[:5].tolist()}


def pyvale_calibration(cam_a: Camera, cam_b: Camera) -> dict:
    """``pyvale.calib.Calib`` fields: ``cam_a`` is pyvale's camera 0, ``cam_b`` camera 1;
    X_b = Rz(psi)·Ry(phi)·Rx(theta)·X_a + T with ``rotation`` = [theta, phi, psi] (deg) and
    ``translation`` = T (mm), from the two world→camera poses."""
    Ra, Rb = cam_a.rotation, cam_b.rotation
    R = Rb @ Ra.T
    T = cam_b.translation - R @ cam_a.translation
    return {"convention": "X_cam1 = Rz(psi) Ry(phi) Rx(theta) X_cam0 + T; rotation = [theta, phi, psi] "
                          "deg, translation = T mm; OpenCV distortion [k1, k2, p1, p2, k3]",
            "cam0": pyvale_intrinsics(cam_a), "cam1": pyvale_intrinsics(cam_b),
            "translation": T.tolist(), "rotation": euler_xyz(R).tolist()}


def write_rig_yaml(path, K1, D1, K2, D2, R, T, image_size, **extra) -> Path:
    """OpenCV FileStorage YAML: image_size [W, H], K1 D1 K2 D2 (D = k1 k2 p1 p2 k3 …), R, T
    (X_cam2 = R·X_cam1 + T, mm), the same extrinsics as MatchID's Tx Ty Tz (mm) and
    Theta Phi Psi (deg), then ``extra`` (matrices or numbers). Written atomically."""
    import cv2
    path = Path(path)
    with io.atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        fs.write("image_size", np.asarray(image_size, np.int32).reshape(1, 2))
        for name, m in (("K1", K1), ("D1", D1), ("K2", K2), ("D2", D2), ("R", R), ("T", T)):
            fs.write(name, np.asarray(m, np.float64).reshape(-1, 3) if name in ("K1", "K2", "R")
                     else np.asarray(m, np.float64).reshape(1, -1) if name.startswith("D")
                     else np.asarray(m, np.float64).reshape(3, 1))
        for name, v in zip(("Tx", "Ty", "Tz"), np.ravel(T)):
            fs.write(name, float(v))
        for name, v in zip(("Theta", "Phi", "Psi"), euler_xyz(R)):
            fs.write(name, v)
        for name, v in extra.items():
            fs.write(name, np.asarray(v, np.float64) if np.ndim(v) else float(v))
        fs.release()
    return path


def read_rig_yaml(path) -> dict[str, np.ndarray]:
    """The matrices of a rig YAML (K1 D1 K2 D2 R T image_size), as written by write_rig_yaml."""
    import cv2
    path = Path(path)
    if not path.is_file():
        raise SceneError(str(path), "file not found", "give a calibration YAML written by glsim calib")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    out = {k: fs.getNode(k).mat() for k in ("K1", "D1", "K2", "D2", "R", "T", "image_size")}
    fs.release()
    missing = [k for k, v in out.items() if v is None]
    if missing:
        raise SceneError(str(path), f"has no {', '.join(missing)}", "give a calibration YAML written by glsim calib")
    out["D1"], out["D2"], out["T"] = out["D1"].ravel(), out["D2"].ravel(), out["T"].ravel()
    out["image_size"] = tuple(int(v) for v in out["image_size"].ravel())
    return out


def opencv_distortion(cam: Camera) -> np.ndarray:
    """The camera's coefficients as OpenCV's shortest sufficient distCoeffs (5, 8 or 12)."""
    c = cam.distortion.coeffs
    n = 12 if np.any(c[8:]) else 8 if np.any(c[5:8]) else 5
    return c[:n]
