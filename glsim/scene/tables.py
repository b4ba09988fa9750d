"""Tables (TOML/JSON data) → the scene's frozen dataclasses, with errors naming the key: the
scene file's top level (``SECTIONS``), type coercion (:func:`coerce`), a dataclass from its
table (:func:`build`), unknown keys (:func:`reject_unknown`), and the ``pose`` table that
places a camera or the specimen (:class:`Pose`). Used by :mod:`glsim.scene.model` and
:mod:`glsim.scene.load`."""
from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from dataclasses import MISSING, dataclass

import numpy as np

from glsim.errors import SceneError, check
from glsim.limits import MAX_COORDINATE_MM
from glsim.scene.camera import Camera, check_rotation, look_at, rodrigues, stereo_pose

Vec3 = tuple[float, float, float]
INT64 = (-2 ** 63, 2 ** 63)   # [low, high) of a TOML integer
Mat3 = tuple[Vec3, Vec3, Vec3]


@dataclass(frozen=True)
class Stereo:
    """A camera relative to the first one (MatchID convention), mm and degrees:
    X_cam = Rz(Psi)·Ry(Phi)·Rx(Theta)·X_cam0 + (Tx, Ty, Tz)."""
    Tx: float
    Ty: float
    Tz: float
    Theta: float
    Phi: float
    Psi: float

    def __post_init__(self):
        for k in ("Tx", "Ty", "Tz"):
            check_length(getattr(self, k), k, "camera 1's offset from camera 0")


@dataclass(frozen=True)
class LookAt:
    """A camera at ``eye`` looking at ``target``, image-up as close to ``up`` as possible (mm)."""
    eye: Vec3
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, -1.0, 0.0)

    def __post_init__(self):
        for k in ("eye", "target"):
            check_length(getattr(self, k), k, "a point in the world frame")
        look_at(self.eye, self.target, self.up)  # raises SceneError("target" or "up") if degenerate


@dataclass(frozen=True)
class Pose:
    """A ``pose`` table: ``R`` (3×3) or ``rvec`` (Rodrigues, rad) and ``t`` (mm), or, for
    cameras only, ``stereo`` or ``look_at`` alone. Missing parts are the identity."""
    R: Mat3 | None = None
    rvec: Vec3 | None = None
    t: Vec3 | None = None
    stereo: Stereo | None = None
    look_at: LookAt | None = None

    def __post_init__(self):
        given = [f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None]
        for whole in ("stereo", "look_at"):
            check(whole not in given or len(given) == 1, whole,
                  f"cannot be combined with {', '.join(k for k in given if k != whole)}",
                  f"{whole} sets the whole pose: remove the other keys")
        check(self.R is None or self.rvec is None, "rvec", "R is given too",
              "give the rotation either as R or as rvec")
        if self.rvec is not None:
            angle = float(np.linalg.norm(self.rvec))
            check(angle <= math.pi + 1e-9, "rvec",
                  f"{list(self.rvec)} turns by |rvec| = {angle:.4g} rad ({math.degrees(angle):.4g}°), "
                  f"more than π: it looks like degrees",
                  f"rvec is in radians (axis × angle): write {_radians(self.rvec)} for these degrees, "
                  f"or give the rotation as R")
        if self.R is not None:
            check_rotation(self.R)
        if self.t is not None:
            check_length(self.t, "t", "the translation")

    def matrices(self, first: Camera | None, camera: bool) -> tuple[np.ndarray, np.ndarray]:
        """(R, t): world→camera for a camera (``first`` is the first camera, None for itself),
        specimen→world otherwise."""
        whole = "stereo" if self.stereo is not None else "look_at" if self.look_at is not None else ""
        check(not whole or camera, whole, "only cameras can be placed this way",
              "place the specimen with R or rvec, and t")
        if self.look_at is not None:
            return look_at(self.look_at.eye, self.look_at.target, self.look_at.up)
        if self.stereo is not None:
            check(first is not None, "stereo", "is relative to the first camera, so only later cameras "
                  "can have it", "give the first camera R or rvec and t, or no pose (the world frame)")
            return stereo_pose(first.rotation, first.translation, *dataclasses.astuple(self.stereo))
        R = np.eye(3) if self.R is None else np.array(self.R, float)
        t = np.zeros(3) if self.t is None else np.array(self.t, float)
        return (R if self.rvec is None else rodrigues(self.rvec)), t


def check_length(value, key: str, what: str) -> None:
    """SceneError(key) unless every entry of the length or point ``value`` (mm) lies within
    ±MAX_COORDINATE_MM (:mod:`glsim.limits`): 1e308 is finite, but its products are not."""
    far = float(np.max(np.abs(value)))
    check(far <= MAX_COORDINATE_MM, key, f"{_number(value)} mm lies beyond glsim's limit of ±{MAX_COORDINATE_MM:g} mm",
          f"give {what} in mm (glsim's lengths and positions lie within ±{MAX_COORDINATE_MM:g} mm)")


def _number(value) -> str:
    """A number or a list of numbers, compactly (%g)."""
    return f"{value:g}" if np.ndim(value) == 0 else "[" + ", ".join(f"{v:g}" for v in value) + "]"


def _radians(degrees) -> str:
    return "[" + ", ".join(f"{math.radians(v):.4g}" for v in degrees) + "]"


def as_tuple(a: np.ndarray) -> tuple:
    """An array as (nested) tuples of Python numbers, as the frozen dataclasses hold them."""
    return tuple(map(tuple, a.tolist())) if a.ndim == 2 else tuple(a.tolist())


def reject_unknown(given, allowed, key: str) -> None:
    """Raise for the first of the keys ``given`` in table ``key`` ("" = top level) not ``allowed``."""
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        close = difflib.get_close_matches(unknown[0], allowed, 1)
        hint = (f"did you mean {close[0]!r}? " if close else
                "top-level keys must come before the first [table]; " if key and unknown[0] in SECTIONS else "")
        raise SceneError(f"{key}.{unknown[0]}" if key else unknown[0], "unknown key",
                         f"{hint}allowed keys in {key or 'the top level'}: {', '.join(allowed)}")


def within(exc: SceneError, key: str) -> SceneError:
    """``exc`` from a validator of the table at ``key``, with its key made a full scene path.

    Validators name keys relative to themselves (Camera: ``fx``; Distortion: ``distortion.k1``)
    or in full (Plate: ``specimen.plate.nx``): ``cameras[0]`` + ``fx`` → ``cameras[0].fx``,
    ``cameras[0].distortion`` + ``distortion.k1`` → ``cameras[0].distortion.k1``.
    """
    if not key or exc.key == key or exc.key.startswith((key + ".", key + "[")):
        return exc
    own = key.rpartition(".")[2].partition("[")[0]          # "cameras[0].distortion" → "distortion"
    rest = exc.key[len(own):] if exc.key == own or exc.key.startswith(own + ".") else "." + exc.key
    problem, _, fix = str(exc)[len(exc.key) + 2:].partition(" — ")
    return SceneError(key + rest, problem, fix)


def coerce(value, hint, key: str):
    """Convert a TOML value to the annotated type, or raise a SceneError naming ``key``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if type(None) in args:                                   # X | None
        return coerce(value, next(a for a in args if a is not type(None)), key)
    if dataclasses.is_dataclass(hint):
        return build(hint, value, key)
    if hint is tuple or origin is tuple:                     # tuple, tuple[X, ...], tuple[X, Y, Z]
        if not isinstance(value, list):
            raise SceneError(key, f"expected a list, got {value!r}", "write e.g. [1, 2, 3]")
        if not args:
            return tuple(tuple(v) if isinstance(v, list) else v for v in value)
        if args[-1] is not Ellipsis and len(value) != len(args):
            raise SceneError(key, f"expected a list of {len(args)}, got {value!r}",
                             f"give exactly {len(args)} entries")
        hints = [args[0]] * len(value) if args[-1] is Ellipsis else args
        return tuple(coerce(v, h, f"{key}[{i}]") for i, (v, h) in enumerate(zip(value, hints)))
    if hint in (int, float):
        if isinstance(value, bool) or not isinstance(value, int if hint is int else (int, float)):
            raise SceneError(key, f"expected {'an integer' if hint is int else 'a number'}, got {value!r}",
                             "write e.g. 4" if hint is int else "write e.g. 1.0")
        if isinstance(value, int) and not INT64[0] <= value < INT64[1]:   # TOML's integers are 64-bit; float() overflows
            digits = str(value)
            shown = digits if len(digits) <= 24 else f"{digits[:24]}… ({len(digits)} digits)"
            raise SceneError(key, f"{shown} is beyond 64-bit integers", "give a number within ±2⁶³ (±9.2e18)")
        if not math.isfinite(value):
            raise SceneError(key, f"must be finite, got {value}", "give a finite number")
        return hint(value)
    if hint in (str, bool) and not isinstance(value, hint):
        raise SceneError(key, f"expected {'a string' if hint is str else 'true or false'}, got {value!r}",
                         'write it in quotes, e.g. "x"' if hint is str else "write true or false")
    return value


SECTIONS = ("cameras", "specimen", "speckle", "render", "output", "lighting", "optics", "noise",
            "sensor", "psf", "vignetting", "exposure", "seed")  # top level of a file

# Values a TOML table may leave out although the dataclass requires them.
TABLE_DEFAULTS = {Camera: {"name": "reference"}}


def build(cls, table, key: str, first: Camera | None = None, **defaults):
    """Build dataclass ``cls`` from the TOML table at ``key``.

    Unknown keys, wrong types, missing required keys and the class's own checks all raise
    a SceneError naming the full key. A class placed by fields R and t (Camera, Specimen) takes
    a ``pose`` table (see Pose) instead of them; ``first`` is the first camera, for stereo poses.
    """
    if not isinstance(table, dict):
        raise SceneError(key, f"expected a table, got {table!r}", f"write {key} as a table of key = value")
    fields = [f for f in dataclasses.fields(cls) if f.init]
    names = [f.name for f in fields]
    posed = cls is not Pose and {"R", "t"} <= set(names)       # Camera, Specimen
    allowed = [n for n in names if not (posed and n in ("R", "t"))] + ["pose"] * posed
    reject_unknown(table, allowed, key)
    hints = typing.get_type_hints(cls)
    kwargs = {**TABLE_DEFAULTS.get(cls, {}), **defaults}
    for name, value in table.items():
        if name == "pose":
            pose = coerce(value, Pose, f"{key}.pose")
            try:
                R, t = pose.matrices(first, camera=cls is Camera)
            except SceneError as exc:
                raise within(exc, f"{key}.pose") from None
            kwargs.update(R=as_tuple(R), t=as_tuple(t))
        else:
            kwargs[name] = coerce(value, hints[name], f"{key}.{name}")
    missing = [f.name for f in fields
               if f.name not in kwargs and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise SceneError(f"{key}.{missing[0]}", "is required", f"add {', '.join(missing)} to {key}")
    try:
        return cls(**kwargs)
    except SceneError as exc:
        raise within(exc, key) from None
