"""Calibration files: a stereo rig written in the conventions DIC packages read.

OpenCV FileStorage YAML (:func:`write_rig_yaml`, :func:`read_rig_yaml`) and pyvale's
``Calib`` fields (:func:`pyvale_calibration`). Every writer takes the world→camera poses of
:class:`~glsim.scene.camera.Camera` (OpenCV axes, mm) and states the stereo extrinsics as
camera 1 relative to camera 0: X_cam1 = R·X_cam0 + T, R = Rz(Psi)·Ry(Phi)·Rx(Theta)
(:func:`euler_xyz` gives Theta, Phi, Psi in degrees, as MatchID and pyvale name them).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError, SceneError
from glsim.limits import not_a_file
from glsim.io import images as io
from glsim.scene.camera import Camera


def euler_xyz(R) -> np.ndarray:
    """(theta, phi, psi) in degrees with R = Rz(psi)·Ry(phi)·Rx(theta), the inverse of
    :func:`glsim.scene.camera.rotation_xyz` (phi in (−90°, 90°))."""
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
    R, T = stereo_extrinsics(cam_a, cam_b)
    return {"convention": "X_cam1 = Rz(psi) Ry(phi) Rx(theta) X_cam0 + T; rotation = [theta, phi, psi] "
                          "deg, translation = T mm; OpenCV distortion [k1, k2, p1, p2, k3]",
            "cam0": pyvale_intrinsics(cam_a), "cam1": pyvale_intrinsics(cam_b),
            "translation": T.tolist(), "rotation": euler_xyz(R).tolist()}


def write_rig_yaml(path, K1, D1, K2, D2, R, T, image_size, *, atomic: bool = True, **extra) -> Path:
    """OpenCV FileStorage YAML: image_size [W, H], K1 D1 K2 D2 (D = k1 k2 p1 p2 k3 …), R, T
    (X_cam1 = R·X_cam0 + T, mm), the same extrinsics as MatchID's Tx Ty Tz (mm) and
    Theta Phi Psi (deg), then ``extra`` (matrices or numbers). Written atomically, or with
    ``atomic`` False straight to ``path`` (a temporary that the caller renames: renaming one
    temporary onto another would replace the caller's file)."""
    path = Path(path)
    if not atomic:
        _rig_yaml(path, K1, D1, K2, D2, R, T, image_size, extra)
        return path
    with io.atomic_path(path) as tmp:
        _rig_yaml(tmp, K1, D1, K2, D2, R, T, image_size, extra)
    return path


def _rig_yaml(path: Path, K1, D1, K2, D2, R, T, image_size, extra: dict) -> None:
    """:func:`write_rig_yaml`'s file, written at ``path``."""
    import cv2
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
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


def read_rig_yaml(path) -> dict[str, np.ndarray]:
    """The matrices of a rig YAML (K1 D1 K2 D2 R T image_size), as written by write_rig_yaml."""
    path = Path(path)
    fix = "give a calibration YAML written by glsim calib"
    text = rig_text(path, fix)
    if not text.strip():   # cv2.FileStorage fails on it with a SystemError
        raise SceneError(str(path), "is empty", fix)
    import cv2             # (after the checks: a refusal needs no OpenCV)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        out = {k: fs.getNode(k).mat() for k in ("K1", "D1", "K2", "D2", "R", "T", "image_size")}
        fs.release()
    except (cv2.error, SystemError) as exc:   # cv2 raises its error inside the constructor as a SystemError
        why = exc.__context__ if isinstance(exc, SystemError) and exc.__context__ is not None else exc
        detail = str(getattr(why, "func", "") or getattr(why, "err", "") or why).strip() or type(why).__name__
        raise SceneError(str(path), f"is not an OpenCV FileStorage YAML file (OpenCV: {detail[:200]})", fix) from None
    missing = [k for k, v in out.items() if v is None]
    if missing:
        raise SceneError(str(path), f"has no {', '.join(missing)}", fix)
    for k, sizes in (("K1", (9,)), ("K2", (9,)), ("R", (9,)), ("T", (3,)), ("image_size", (2,)),
                     ("D1", (4, 5, 8, 12, 14)), ("D2", (4, 5, 8, 12, 14))):
        if out[k].size not in sizes or not np.isfinite(out[k]).all():
            raise SceneError(f"{path}: {k}", f"holds {out[k].size} values ({out[k].shape}), not {' or '.join(map(str, sizes))} "
                             "finite numbers", fix)
    out["K1"], out["K2"], out["R"] = (out[k].reshape(3, 3) for k in ("K1", "K2", "R"))
    out["D1"], out["D2"], out["T"] = out["D1"].ravel(), out["D2"].ravel(), out["T"].ravel()
    out["image_size"] = tuple(int(v) for v in out["image_size"].ravel())
    return out


def opencv_distortion(cam: Camera) -> np.ndarray:
    """The camera's coefficients as OpenCV's shortest sufficient distCoeffs (5, 8 or 12)."""
    c = cam.distortion.coeffs
    n = 12 if np.any(c[8:]) else 8 if np.any(c[5:8]) else 5
    return c[:n]


# ---- one rig, four formats ---------------------------------------------------------------------
# A rig is two glsim Cameras (world→camera poses, OpenCV intrinsics and distortion). Formats that
# store camera 1 relative to camera 0 (OpenCV YAML, MatchID, pyvale) read back with camera 0 as the
# world frame; DICe's XML stores each camera's world→camera pose and reads back unchanged.
FORMATS = {"opencv": ".yaml", "matchid": ".caldat", "dice": ".xml", "pyvale": ".json"}
MAX_RIG_BYTES = 1 << 20   # a rig file holds two cameras: a few kB; larger is not one
_BROWN5 = ("k1", "k2", "p1", "p2", "k3")            # what MatchID and pyvale can hold


def stereo_extrinsics(cam_a: Camera, cam_b: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R, T): camera b relative to camera a, X_b = R·X_a + T (mm), as OpenCV's stereoCalibrate."""
    R = cam_b.rotation @ cam_a.rotation.T
    return R, cam_b.translation - R @ cam_a.translation


def _format_of(path: Path, fmt: str | None) -> str:
    if fmt is None:
        fmt = next((f for f, ext in FORMATS.items() if path.suffix.lower() in (ext, ".yml" if f == "opencv" else ext)),
                   None)
        if fmt is None:
            raise SceneError(str(path), f"the extension {path.suffix!r} names no calibration format",
                             f"give --format one of {', '.join(FORMATS)} or a file ending in "
                             f"{', '.join(FORMATS.values())}")
    if fmt not in FORMATS:
        raise SceneError("format", f"{fmt!r} is not a calibration format", f"use one of {', '.join(FORMATS)}")
    return fmt


def _brown5(cam: Camera, fmt: str) -> list[float]:
    """k1 k2 p1 p2 k3, refusing the coefficients ``fmt`` cannot express (by name)."""
    d = cam.distortion
    extra = [n for n in ("k4", "k5", "k6", "s1", "s2", "s3", "s4") if getattr(d, n)]
    if extra:
        raise SceneError(f"cameras.{cam.name}.distortion", f"{fmt} files hold only k1, k2, p1, p2, k3, but "
                         f"{', '.join(extra)} ≠ 0", "export to the opencv or dice format, which hold the full model")
    return [getattr(d, n) for n in _BROWN5]


def _relative_rig(K_a, D_a, K_b, D_b, R, T, size, names=("cam0", "cam1")) -> tuple[Camera, Camera]:
    from glsim.scene.camera import Distortion

    def cam(name, K, D, R_, t_):
        K = np.asarray(K, float)
        return Camera(name=name, size=tuple(size), fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], skew=K[0, 1],
                      distortion=Distortion.from_opencv(D), R=np.asarray(R_, float), t=np.asarray(t_, float))
    return cam(names[0], K_a, D_a, np.eye(3), np.zeros(3)), cam(names[1], K_b, D_b, R, T)


def rig_text(path: Path, fix: str) -> str:
    """The text of the rig file ``path``, checked before any parser sees it: a regular file of at
    most MAX_RIG_BYTES, UTF-8 without NUL bytes; else SceneError(path) with ``fix``."""
    why = not_a_file(path)
    if why:
        raise SceneError(str(path), "file not found" if why == "not found" else why, fix)
    size = path.stat().st_size
    if size > MAX_RIG_BYTES:
        raise SceneError(str(path), f"is {size:,} bytes, more than a rig file's {MAX_RIG_BYTES:,}", fix)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(str(path), f"is not UTF-8 text ({exc.reason} at byte {exc.start})", fix) from None
    if "\0" in text:
        raise SceneError(str(path), f"holds a NUL byte at character {text.index(chr(0))}: it is not text", fix)
    return text


def _key_value_lines(path: Path) -> dict[str, str]:
    out = {}
    for i, line in enumerate(rig_text(path, "give a MatchID .caldat file").splitlines(), 1):
        if line.strip():
            if ";" not in line:
                raise SceneError(f"{path}:{i}", f"{line.strip()!r} is not a 'key;value' line",
                                 "give a MatchID .caldat file (one 'key;value' per line)")
            key, value = line.split(";", 1)
            out[key.strip()] = value.strip()
    return out


def _number(table: dict, key: str, path: Path) -> float:
    try:
        return float(table[key])
    except KeyError:
        raise SceneError(str(path), f"has no {key!r}", "give a complete calibration file") from None
    except ValueError:
        raise SceneError(f"{path}: {key}", f"{table[key]!r} is not a number", "fix the value") from None


def write_matchid(path, cam_a: Camera, cam_b: Camera) -> Path:
    """MatchID ``.caldat``: ``key;value`` lines, camera 0 = ``cam_a``; Kappa 1–3 = k1, k2, k3 and
    P1, P2 = p1, p2 (the order pyvale's writer uses); Tx Ty Tz (mm) and Theta Phi Psi (deg) with
    X_cam1 = Rz(Psi)·Ry(Phi)·Rx(Theta)·X_cam0 + T."""
    lines = []
    for i, cam in enumerate((cam_a, cam_b)):
        k1, k2, p1, p2, k3 = _brown5(cam, "matchid")
        lines += [f"Cam{i}_Fx [pixels];{cam.fx!r}", f"Cam{i}_Fy [pixels];{cam.fy!r}", f"Cam{i}_Fs [pixels];{cam.skew!r}",
                  f"Cam{i}_Kappa 1;{k1!r}", f"Cam{i}_Kappa 2;{k2!r}", f"Cam{i}_Kappa 3;{k3!r}",
                  f"Cam{i}_P1;{p1!r}", f"Cam{i}_P2;{p2!r}", f"Cam{i}_Cx [pixels];{cam.cx!r}",
                  f"Cam{i}_Cy [pixels];{cam.cy!r}"]
    R, T = stereo_extrinsics(cam_a, cam_b)
    lines += [f"{n} [mm];{float(v)!r}" for n, v in zip(("Tx", "Ty", "Tz"), T)]
    lines += [f"{n} [deg];{float(v)!r}" for n, v in zip(("Theta", "Phi", "Psi"), euler_xyz(R))]
    return io.write_text(Path(path), "\n".join(lines) + "\n")


def read_matchid(path, image_size) -> tuple[Camera, Camera]:
    """A ``.caldat`` as two Cameras (camera 0 the world frame); the file has no image size."""
    from glsim.scene.camera import rotation_xyz

    path = Path(path)
    t = _key_value_lines(path)
    g = lambda k: _number(t, k, path)  # noqa: E731
    Ks, Ds = [], []
    for i in (0, 1):
        Ks.append([[g(f"Cam{i}_Fx [pixels]"), g(f"Cam{i}_Fs [pixels]"), g(f"Cam{i}_Cx [pixels]")],
                   [0, g(f"Cam{i}_Fy [pixels]"), g(f"Cam{i}_Cy [pixels]")], [0, 0, 1]])
        Ds.append([g(f"Cam{i}_Kappa 1"), g(f"Cam{i}_Kappa 2"), g(f"Cam{i}_P1"), g(f"Cam{i}_P2"), g(f"Cam{i}_Kappa 3")])
    R = rotation_xyz(g("Theta [deg]"), g("Phi [deg]"), g("Psi [deg]"))
    T = [g("Tx [mm]"), g("Ty [mm]"), g("Tz [mm]")]
    return _relative_rig(Ks[0], Ds[0], Ks[1], Ds[1], R, T, image_size)


_DICE_INTRINSICS = ("CX", "CY", "FX", "FY", "FS", "K1", "K2", "K3", "K4", "K5", "K6", "P1", "P2", "S1", "S2", "S3", "S4")


def write_dice(path, cam_a: Camera, cam_b: Camera) -> Path:
    """DICe camera-system XML (``DICe_xml_camera_system_file``, Teuchos ParameterList): per camera
    ``CAMERA i`` with CX CY FX FY FS K1–K6 P1 P2 S1–S4 (OpenCV's model,
    ``LENS_DISTORTION_MODEL = OPENCV_LENS_DISTORTION``), its world→camera pose as TX TY TZ (mm)
    and a ``rotation_3x3_matrix`` (rows ``ROW 0``–``ROW 2``), and ``IMAGE_HEIGHT_WIDTH {H, W}``."""
    import xml.etree.ElementTree as ET

    root = ET.Element("ParameterList")

    def param(parent, name, type_, value):
        ET.SubElement(parent, "Parameter", name=name, type=type_, value=value)
    param(root, "xml_file_format", "string", "DICe_xml_camera_system_file")
    param(root, "system_type_3D", "string", "GENERIC_SYSTEM")
    for i, cam in enumerate((cam_a, cam_b)):
        c = ET.SubElement(root, "ParameterList", name=f"CAMERA {i}")
        d = cam.distortion
        values = {"CX": cam.cx, "CY": cam.cy, "FX": cam.fx, "FY": cam.fy, "FS": cam.skew,
                  **{n.upper(): getattr(d, n) for n in ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2",
                                                        "s1", "s2", "s3", "s4")}}
        for name in _DICE_INTRINSICS:
            param(c, name, "double", repr(float(values[name])))
        param(c, "LENS_DISTORTION_MODEL", "string", "OPENCV_LENS_DISTORTION")
        param(c, "IMAGE_HEIGHT_WIDTH", "string", f"{{ {cam.size[1]}, {cam.size[0]} }}")
        for n, v in zip(("TX", "TY", "TZ"), cam.translation):
            param(c, n, "double", repr(float(v)))
        rot = ET.SubElement(c, "ParameterList", name="rotation_3x3_matrix")
        for j, row in enumerate(cam.rotation):
            param(rot, f"ROW {j}", "string", "{ " + ", ".join(repr(float(v)) for v in row) + " }")
    ET.indent(root)
    return io.write_text(Path(path), ET.tostring(root, encoding="unicode") + "\n")


def read_dice(path) -> tuple[Camera, Camera]:
    """A DICe camera-system XML (as :func:`write_dice` writes it, or with ALPHA BETA GAMMA angles in
    degrees, R = Rz(GAMMA)·Ry(BETA)·Rx(ALPHA)) as two Cameras with their world→camera poses."""
    import xml.etree.ElementTree as ET

    from glsim.scene.camera import Distortion, rotation_xyz

    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise SceneError(str(path), f"is not valid XML ({exc})", "give a DICe camera-system XML file") from None
    top = {p.get("name"): p.get("value") for p in root.findall("Parameter")}
    if top.get("xml_file_format") != "DICe_xml_camera_system_file":
        raise SceneError(str(path), "has no xml_file_format = DICe_xml_camera_system_file",
                         "give a DICe camera-system XML file")
    if top.get("extrinsics_relative_camera_to_camera", "false").lower() == "true":
        raise SceneError(f"{path}: extrinsics_relative_camera_to_camera", "camera-to-camera extrinsics are not read",
                         "export the rig with world→camera extrinsics per camera")
    cams = []
    for i in (0, 1):
        node = root.find(f"ParameterList[@name='CAMERA {i}']")
        if node is None:
            raise SceneError(str(path), f"has no 'CAMERA {i}' list", "give a two-camera DICe system file")
        p = {q.get("name"): q.get("value") for q in node.findall("Parameter")}
        model = p.get("LENS_DISTORTION_MODEL", "NO_LENS_DISTORTION")
        if model not in ("OPENCV_LENS_DISTORTION", "NO_LENS_DISTORTION"):
            raise SceneError(f"{path}: CAMERA {i}.LENS_DISTORTION_MODEL", f"{model} is not OpenCV's model",
                             "only OPENCV_LENS_DISTORTION (or none) maps onto glsim's camera model")
        g = lambda k: _number(p, k, path) if k in p else 0.0  # noqa: E731
        try:
            H, W = (int(v) for v in p["IMAGE_HEIGHT_WIDTH"].strip("{} ").split(","))
        except (KeyError, ValueError):
            raise SceneError(f"{path}: CAMERA {i}.IMAGE_HEIGHT_WIDTH", "is missing or not '{ H, W }'",
                             "give the image size") from None
        rot = node.find("ParameterList[@name='rotation_3x3_matrix']")
        if rot is not None:
            rows = {q.get("name"): q.get("value") for q in rot.findall("Parameter")}
            R = [[float(v) for v in rows[f"ROW {j}"].strip("{} ").split(",")] for j in range(3)]
        else:
            R = rotation_xyz(g("ALPHA"), g("BETA"), g("GAMMA"))
        dist = Distortion(**{n: g(n.upper()) for n in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
                                                        "s1", "s2", "s3", "s4")})
        cams.append(Camera(name=f"cam{i}", size=(W, H), fx=g("FX"), fy=g("FY"), cx=g("CX"), cy=g("CY"), skew=g("FS"),
                           distortion=dist, R=np.asarray(R, float), t=[g("TX"), g("TY"), g("TZ")]))
    return cams[0], cams[1]


def write_pyvale(path, cam_a: Camera, cam_b: Camera) -> Path:
    """pyvale's ``Calib`` fields as JSON (:func:`pyvale_calibration`), plus the image size."""
    import json
    for cam in (cam_a, cam_b):
        _brown5(cam, "pyvale")
    return io.write_text(Path(path), json.dumps({**pyvale_calibration(cam_a, cam_b), "image_size": list(cam_a.size)},
                                                indent=2) + "\n")


def read_pyvale(path, image_size=None) -> tuple[Camera, Camera]:
    import json

    from glsim.scene.camera import rotation_xyz

    path = Path(path)
    try:
        d = json.loads(rig_text(path, "give a file written by glsim rig export --format pyvale"))
        Ks = [[[c["fx"], c["fs"], c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]] for c in (d["cam0"], d["cam1"])]
        Ds = [d["cam0"]["distortion"], d["cam1"]["distortion"]]
        R, T = rotation_xyz(*d["rotation"]), d["translation"]
        size = d.get("image_size", image_size)
    except (ValueError, KeyError, TypeError) as exc:
        raise SceneError(str(path), f"is not a pyvale calibration JSON ({type(exc).__name__}: {exc})",
                         "give a file written by glsim rig export --format pyvale") from None
    return _relative_rig(Ks[0], Ds[0], Ks[1], Ds[1], R, T, _size(size, path))


def _size(size, path: Path) -> tuple[int, int]:
    if size is None:
        raise SceneError(str(path), "holds no image size", "give the image size (--size W H)")
    return tuple(int(v) for v in size)


def export_rig(path, cam_a: Camera, cam_b: Camera, fmt: str | None = None) -> Path:
    """Write the rig ``cam_a`` (camera 0) + ``cam_b`` (camera 1) in ``fmt`` (from the extension if
    None), atomically; a model the format cannot hold is refused by name before anything is written."""
    path = Path(path)
    fmt = _format_of(path, fmt)
    if fmt == "opencv":
        R, T = stereo_extrinsics(cam_a, cam_b)
        return write_rig_yaml(path, cam_a.K, opencv_distortion(cam_a), cam_b.K, opencv_distortion(cam_b), R, T,
                              cam_a.size)
    return {"matchid": write_matchid, "dice": write_dice, "pyvale": write_pyvale}[fmt](path, cam_a, cam_b)


def import_rig(path, fmt: str | None = None, image_size=None) -> tuple[Camera, Camera]:
    """Read a rig written in any of :data:`FORMATS` as two Cameras. Relative formats put camera 0
    at the world origin; ``image_size`` (W, H) is needed for MatchID files, which hold none."""
    path = Path(path)
    fmt = _format_of(path, fmt)
    why = not_a_file(path)
    if why:
        raise SceneError(str(path), "file not found" if why == "not found" else why, "check the path")
    if fmt == "opencv":
        y = read_rig_yaml(path)
        return _relative_rig(y["K1"], y["D1"], y["K2"], y["D2"], y["R"], y["T"], y["image_size"])
    if fmt == "matchid":
        return read_matchid(path, _size(image_size, path))
    if fmt == "dice":
        return read_dice(path)
    return read_pyvale(path, image_size)
