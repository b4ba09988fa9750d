"""Scene description: frozen dataclasses (no GL handles) and the TOML loader that fills them.

A scene file has the same structure as these dataclasses: ``[[cameras]]``, ``[speckle]``,
``[specimen]``, ``[render]``, ``[output]`` and a top-level ``seed``. Every key is checked:
unknown keys, wrong types and impossible values raise :class:`SceneError` naming the key.
Units: millimetres, pixels, degrees for the stereo angles.
"""
from __future__ import annotations

import dataclasses
import json
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .camera import Camera, Distortion, look_at, rodrigues, stereo_pose
from .errors import SceneError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

MODES = ("fast", "q4", "exact")
INTERPOLATIONS = ("linear", "cubic", "bspline3", "bspline5")
BACKENDS = ("gl", "cpu")
PRECISIONS = ("fp32", "fp64")
FORMATS = ("tiff", "png")


@dataclass(frozen=True)
class Speckle:
    """The reference speckle image and the virtual reference camera that "took" it.

    Either ``image`` (a greyscale file, 8/16-bit or float in [0, 1]) or the built-in
    generator (``image`` empty). The reference camera is ``camera`` if given, otherwise a
    pinhole looking square onto the undeformed specimen at ``mm_per_px`` mm per reference
    pixel; for the generator ``mm_per_px`` defaults to camera 1's scale at the specimen
    divided by ``oversample``.
    """
    image: str = ""
    camera: Camera | None = None
    mm_per_px: float = 0.0
    dot_diameter_px: float = 5.0   # in camera-1 pixels on the specimen
    density: float = 0.5
    oversample: float = 2.0        # reference pixels per camera-1 pixel
    seed: int = 0

    def __post_init__(self):
        _check(self.mm_per_px >= 0, "speckle.mm_per_px", f"must be ≥ 0, got {self.mm_per_px}",
               "give the reference image scale in mm per pixel (0 = automatic)")
        _check(self.oversample > 0, "speckle.oversample", f"must be > 0, got {self.oversample}",
               "reference pixels per camera pixel, typically 2–4")
        _check(self.dot_diameter_px >= 2.0, "speckle.dot_diameter_px",
               f"must be ≥ 2 px, got {self.dot_diameter_px}",
               "DIC needs speckles of at least 3 camera pixels")
        _check(0 < self.density < 1, "speckle.density", f"must lie in (0, 1), got {self.density}",
               "the covered area fraction, typically 0.5")


@dataclass(frozen=True)
class Plate:
    """Built-in flat rectangular plate in its local XY plane, with rigid translations per step."""
    width: float = 40.0
    height: float = 30.0
    nx: int = 8
    ny: int = 6
    translations: tuple = ()       # one (dx, dy, dz) in mm per load step after step 0

    def __post_init__(self):
        for k in ("width", "height"):
            _check(getattr(self, k) > 0, f"specimen.plate.{k}", "must be > 0", "give it in mm")
        for k in ("nx", "ny"):
            _check(getattr(self, k) >= 1, f"specimen.plate.{k}", "must be ≥ 1", "element count")
        for i, tr in enumerate(self.translations):
            _check(len(tr) == 3, f"specimen.plate.translations[{i}]", "must have 3 entries",
                   "give [dx, dy, dz] in mm")


@dataclass(frozen=True)
class Bulge:
    """Built-in bulge test (paper Table 2): clamped circular plate with the analytic field."""
    radius: float = 50.0
    thickness: float = 3.0
    w0: float = 5.0
    steps: int = 3
    n_core: int = 8
    n_ring: int = 8

    def __post_init__(self):
        for k in ("radius", "thickness"):
            _check(getattr(self, k) > 0, f"specimen.bulge.{k}", "must be > 0", "give it in mm")
        for k in ("steps", "n_core", "n_ring"):
            _check(getattr(self, k) >= 1, f"specimen.bulge.{k}", "must be ≥ 1", "a count")


@dataclass(frozen=True)
class MeshFile:
    """An FE mesh file read with meshio (Abaqus .inp, VTK/VTU, Gmsh .msh) and its steps."""
    path: str = ""
    unit: str = "mm"
    point_data: tuple = ()         # names of per-step displacement arrays in the file
    files: tuple = ()              # one mesh file per step with a displacement field
    csv: tuple = ()                # one `label;ux;uy;uz` file per step
    field: str = ""                # displacement field name in `files`


@dataclass(frozen=True)
class Specimen:
    """The FE specimen: one source (``mesh``, ``plate`` or ``bulge``) and its placement.

    Placement maps specimen coordinates to the world (camera 1's frame by default):
    X_world = R·X + t, mm.
    """
    mesh: MeshFile | None = None
    plate: Plate | None = None
    bulge: Bulge | None = None
    R: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    t: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        given = [k for k in ("mesh", "plate", "bulge") if getattr(self, k) is not None]
        _check(len(given) == 1, "specimen",
               f"exactly one of mesh, plate, bulge must be given, got {given or 'none'}",
               "add e.g. [specimen.bulge] or [specimen.mesh] path = 'model.inp'")


@dataclass(frozen=True)
class Render:
    """How images are made. ``samples_per_pixel`` is a square (1, 4, 9, 16, …): box filter."""
    backend: str = "gl"
    mode: str = "exact"
    interpolation: str = "bspline3"
    samples_per_pixel: int = 1
    background: float = 0.0       # grey level in [0, 1] of full scale
    precision: str = "fp64"       # GL arithmetic of the exact mode's intersection

    def __post_init__(self):
        for key, allowed in (("backend", BACKENDS), ("mode", MODES),
                             ("interpolation", INTERPOLATIONS), ("precision", PRECISIONS)):
            value = getattr(self, key)
            _check(value in allowed, f"render.{key}", f"{value!r} is not one of {allowed}",
                   f"use one of {', '.join(allowed)}")
        s = math.isqrt(max(self.samples_per_pixel, 0))
        _check(self.samples_per_pixel >= 1 and s * s == self.samples_per_pixel,
               "render.samples_per_pixel", f"must be a perfect square ≥ 1, got "
               f"{self.samples_per_pixel}", "use 1, 4, 9, 16, …")
        _check(0.0 <= self.background <= 1.0, "render.background",
               f"must lie in [0, 1], got {self.background}", "a fraction of full scale")

    @property
    def supersampling(self) -> int:
        """Samples per pixel along each axis."""
        return math.isqrt(self.samples_per_pixel)


@dataclass(frozen=True)
class Output:
    """Where and how images are written."""
    directory: str = "glsim-out"
    format: str = "tiff"
    pattern: str = "{camera}_{step:04d}.{ext}"

    def __post_init__(self):
        _check(self.format in FORMATS, "output.format", f"{self.format!r} is not one of {FORMATS}",
               "use 'tiff' (8/16-bit) or 'png'")
        try:
            self.pattern.format(camera="c", step=0, ext="tif")
        except (KeyError, IndexError, ValueError) as exc:
            raise SceneError("output.pattern", f"cannot be formatted ({exc})",
                             "use the fields {camera}, {step} and {ext}") from None


@dataclass(frozen=True)
class Scene:
    """A whole virtual stereo-DIC experiment. ``base_dir`` resolves relative file paths."""
    cameras: tuple[Camera, ...]
    specimen: Specimen = field(default_factory=lambda: Specimen(bulge=Bulge()))
    speckle: Speckle = field(default_factory=Speckle)
    render: Render = field(default_factory=Render)
    output: Output = field(default_factory=Output)
    seed: int = 0
    base_dir: str = "."

    def __post_init__(self):
        _check(len(self.cameras) >= 1, "cameras", "at least one camera is needed",
               "add a [[cameras]] table")
        names = [c.name for c in self.cameras]
        _check(len(set(names)) == len(names), "cameras", f"camera names repeat: {names}",
               "give each camera a unique name")

    def camera(self, which: int | str) -> Camera:
        """A camera by index or name."""
        if isinstance(which, str):
            for cam in self.cameras:
                if cam.name == which:
                    return cam
            raise SceneError("camera", f"no camera named {which!r}",
                             f"use one of {[c.name for c in self.cameras]}")
        if not 0 <= which < len(self.cameras):
            raise SceneError("camera", f"index {which} out of range", f"use 0…{len(self.cameras) - 1}")
        return self.cameras[which]

    def resolve(self, path: str) -> Path:
        """A scene-relative path made absolute."""
        p = Path(path)
        return p if p.is_absolute() else Path(self.base_dir) / p

    def replace(self, **sections) -> "Scene":
        """A copy with some options changed, e.g. ``scene.replace(render={"mode": "q4"})``."""
        changes = {}
        for name, value in sections.items():
            current = getattr(self, name)
            changes[name] = dataclasses.replace(current, **value) if isinstance(value, dict) else value
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The resolved scene (every default filled) as plain JSON-able data."""
        return _plain(dataclasses.asdict(self))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


# --------------------------------------------------------------------------------------------
# Loading


def _check(ok: bool, key: str, problem: str, fix: str) -> None:
    if not ok:
        raise SceneError(key, problem, fix)


def _plain(obj):
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def _coerce(value, hint, key: str):
    """Convert a TOML value to the annotated type, or raise a SceneError naming ``key``."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union or (origin is not None and type(None) in args):
        inner = [a for a in args if a is not type(None)]
        return _coerce(value, inner[0], key)
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, key)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(key, f"expected a number, got {value!r}", "write e.g. 1.0")
        if not math.isfinite(value):
            raise SceneError(key, f"must be finite, got {value}", "give a finite number")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(key, f"expected an integer, got {value!r}", "write e.g. 4")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise SceneError(key, f"expected a string, got {value!r}", 'write it in quotes, e.g. "x"')
        return value
    if hint is tuple or origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SceneError(key, f"expected a list, got {value!r}", "write e.g. [1, 2, 3]")
        return tuple(tuple(v) if isinstance(v, list) else v for v in value)
    return value


def _build(cls, table, key: str):
    """Build dataclass ``cls`` from a TOML table, rejecting unknown keys."""
    if not isinstance(table, dict):
        raise SceneError(key, f"expected a table, got {table!r}", f"write [{key}] with keys")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = sorted(set(table) - set(names))
    if unknown:
        raise SceneError(f"{key}.{unknown[0]}" if key else unknown[0], "unknown key",
                         f"allowed keys in [{key or 'top level'}]: {', '.join(names)}")
    kwargs = {k: _coerce(v, hints[k], f"{key}.{k}" if key else k) for k, v in table.items()}
    try:
        return cls(**kwargs)
    except SceneError as exc:
        if key and not exc.key.startswith(key.split("[")[0].split(".")[0]):
            raise SceneError(f"{key}.{exc.key}", *_split(exc)) from None
        raise


def _split(exc: SceneError) -> tuple[str, str]:
    text = str(exc)[len(exc.key) + 2:]
    problem, _, fix = text.partition(" — ")
    return problem, fix


def _vec(value, n: int, key: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float) if _is_numeric_list(value) else None
    if arr is None or arr.shape != (n,):
        raise SceneError(key, f"expected {n} numbers, got {value!r}", f"write [{', '.join(['0'] * n)}]")
    return arr


def _is_numeric_list(value) -> bool:
    def ok(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) or (
            isinstance(v, (list, tuple)) and all(ok(x) for x in v))
    return isinstance(value, (list, tuple)) and all(ok(v) for v in value)


def _rotation(table: dict, key: str) -> np.ndarray:
    if "R" in table and "rvec" in table:
        raise SceneError(key, "give either R or rvec, not both", "remove one of them")
    if "rvec" in table:
        return rodrigues(_vec(table["rvec"], 3, f"{key}.rvec"))
    if "R" in table:
        R = np.asarray(table["R"], dtype=float) if _is_numeric_list(table["R"]) else None
        if R is None or R.shape != (3, 3):
            raise SceneError(f"{key}.R", f"expected a 3×3 matrix, got {table['R']!r}",
                             "write [[1,0,0],[0,1,0],[0,0,1]] or use rvec")
        return R
    return np.eye(3)


STEREO_KEYS = ("Tx", "Ty", "Tz", "Theta", "Phi", "Psi")


def _pose(table, key: str, first: Camera | None) -> tuple[np.ndarray, np.ndarray]:
    """World→camera (R, t) from {R|rvec, t}, {look_at = {eye, target, up}} or {stereo = {...}}."""
    if not isinstance(table, dict):
        raise SceneError(key, f"expected a table, got {table!r}", "write pose = {rvec = [...], t = [...]}")
    allowed = {"R", "rvec", "t", "stereo", "look_at"}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SceneError(f"{key}.{unknown[0]}", "unknown key", f"allowed: {', '.join(sorted(allowed))}")
    if "stereo" in table:
        if first is None:
            raise SceneError(f"{key}.stereo", "the first camera cannot be given relative to itself",
                             "give camera 1 a pose with R/rvec and t (or none: the world frame)")
        st = table["stereo"]
        missing = [k for k in STEREO_KEYS if k not in st] if isinstance(st, dict) else STEREO_KEYS
        if missing or set(st) - set(STEREO_KEYS):
            raise SceneError(f"{key}.stereo", f"needs exactly the keys {', '.join(STEREO_KEYS)}",
                             "Tx Ty Tz in mm, Theta Phi Psi in degrees (MatchID convention)")
        vals = [_coerce(st[k], float, f"{key}.stereo.{k}") for k in STEREO_KEYS]
        return stereo_pose(first.rotation, first.translation, *vals)
    if "look_at" in table:
        la = table["look_at"]
        eye = _vec(la.get("eye"), 3, f"{key}.look_at.eye")
        target = _vec(la.get("target", [0, 0, 0]), 3, f"{key}.look_at.target")
        up = _vec(la.get("up", [0, -1, 0]), 3, f"{key}.look_at.up")
        return look_at(eye, target, up)
    return _rotation(table, key), _vec(table.get("t", [0, 0, 0]), 3, f"{key}.t")


def _camera(table, key: str, first: Camera | None) -> Camera:
    if not isinstance(table, dict):
        raise SceneError(key, "expected a table", "write [[cameras]] with keys")
    table = dict(table)
    R, t = _pose(table.pop("pose", {}), f"{key}.pose", first)
    dist = table.pop("distortion", {})
    if not isinstance(dist, dict):
        raise SceneError(f"{key}.distortion", f"expected a table, got {dist!r}",
                         "write distortion = {k1 = -0.1, k2 = 0.0, p1 = 0, p2 = 0, k3 = 0}")
    distortion = _build(Distortion, dist, f"{key}.distortion")
    table.setdefault("name", f"cam{0 if first is None else 1}")
    if "size" in table:
        size = table["size"]
        if not (isinstance(size, list) and len(size) == 2 and all(isinstance(s, int) for s in size)):
            raise SceneError(f"{key}.size", f"expected [W, H] integers, got {size!r}",
                             "write size = [1624, 1234]")
    cam = _build_camera(table, key)
    return dataclasses.replace(cam, distortion=distortion, R=_tuple(R), t=_tuple(t))


def _build_camera(table: dict, key: str) -> Camera:
    hints = {"name": str, "size": tuple, "fx": float, "fy": float, "cx": float, "cy": float,
             "skew": float, "bit_depth": int}
    unknown = sorted(set(table) - set(hints))
    if unknown:
        raise SceneError(f"{key}.{unknown[0]}", "unknown key",
                         f"allowed: {', '.join(list(hints) + ['distortion', 'pose'])}")
    missing = [k for k in ("size", "fx", "fy", "cx", "cy") if k not in table]
    if missing:
        raise SceneError(f"{key}.{missing[0]}", "is required", "give the intrinsics in pixels")
    kwargs = {k: _coerce(v, hints[k], f"{key}.{k}") for k, v in table.items()}
    try:
        return Camera(**kwargs)
    except SceneError as exc:
        raise SceneError(f"{key}.{exc.key}", *_split(exc)) from None


def _tuple(a: np.ndarray) -> tuple:
    return tuple(map(tuple, a)) if a.ndim == 2 else tuple(float(x) for x in a)


def scene_from_dict(data: dict, base_dir: str | Path = ".") -> Scene:
    """Build a Scene from parsed TOML (see the module docstring for the layout)."""
    data = dict(data)
    allowed = {"cameras", "specimen", "speckle", "render", "output", "seed"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise SceneError(unknown[0], "unknown top-level key", f"allowed: {', '.join(sorted(allowed))}")
    cams_t = data.get("cameras")
    if not isinstance(cams_t, list) or not cams_t:
        raise SceneError("cameras", "at least one [[cameras]] table is required",
                         "add [[cameras]] with size, fx, fy, cx, cy")
    cameras: list[Camera] = []
    for i, table in enumerate(cams_t):
        cameras.append(_camera(table, f"cameras[{i}]", cameras[0] if cameras else None))
    spec_t = dict(data.get("specimen", {"bulge": {}}))
    pose = spec_t.pop("pose", {})
    R, t = _pose(pose, "specimen.pose", None)
    specimen = _build(Specimen, spec_t, "specimen")
    specimen = dataclasses.replace(specimen, R=_tuple(R), t=_tuple(t))
    speckle_t = dict(data.get("speckle", {}))
    ref_cam = speckle_t.pop("camera", None)
    speckle = _build(Speckle, speckle_t, "speckle")
    if ref_cam is not None:
        speckle = dataclasses.replace(speckle, camera=_camera(ref_cam, "speckle.camera", None))
    return Scene(
        cameras=tuple(cameras), specimen=specimen, speckle=speckle,
        render=_build(Render, data.get("render", {}), "render"),
        output=_build(Output, data.get("output", {}), "output"),
        seed=_coerce(data.get("seed", 0), int, "seed"),
        base_dir=str(Path(base_dir).resolve()))


def load_scene(path: str | Path) -> Scene:
    """Read and validate a TOML scene file."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(str(path), "scene file not found", "check the path")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(str(path), f"is not valid TOML ({exc})", "fix the syntax at that line") from None
    return scene_from_dict(data, path.parent)


# --------------------------------------------------------------------------------------------
# Built-in scenes


def stereo_rig(size=(1624, 1234), fx=6818.0, distance=600.0, stereo_angle=30.0,
               distortion: Distortion = Distortion(), bit_depth: int = 8) -> tuple[Camera, Camera]:
    """Two identical cameras converging by ``stereo_angle`` (deg) on a point ``distance`` mm in
    front of camera 1, which is the world frame. The default is Table 2/3: 30 mm lenses with
    4.4 µm pixels (fx = 6818 px), 1624×1234 px, ≈ 0.088 mm/px at 600 mm."""
    W, H = size
    half = math.radians(stereo_angle / 2)
    target = np.array([0.0, 0.0, distance])
    # Camera 1 at the origin; camera 2 mirrored about the bisector plane of the rig.
    eye2 = np.array([2 * distance * math.sin(half) * math.cos(half),
                     0.0, 2 * distance * math.sin(half) ** 2])
    R2, t2 = look_at(eye2, target, np.array([0.0, -1.0, 0.0]))
    common = dict(size=(W, H), fx=fx, fy=fx, cx=(W - 1) / 2, cy=(H - 1) / 2,
                  distortion=distortion, bit_depth=bit_depth)
    return Camera(name="cam0", **common), Camera(name="cam1", R=_tuple(R2), t=_tuple(t2), **common)


def bulge_scene(size=(1624, 1234), steps: int = 3, **render) -> Scene:
    """The paper's bulge test (Tables 2–3): R = 50 mm plate, 5 mm bulge, 30° stereo rig.

    The plate faces the bisector of the two optical axes, 600 mm from camera 1, and bulges
    towards the cameras.
    """
    cam0, cam1 = stereo_rig(size=size, fx=6818.0 * size[0] / 1624)
    half = math.radians(15.0)
    # The plate's local −z (its bulge direction) points along the rig's bisector, to the cameras.
    Rp = np.array([[math.cos(half), 0, -math.sin(half)], [0, 1, 0], [math.sin(half), 0, math.cos(half)]])
    specimen = Specimen(bulge=Bulge(steps=steps), R=_tuple(Rp), t=(0.0, 0.0, 600.0))
    return Scene(cameras=(cam0, cam1), specimen=specimen, render=Render(**render))
