"""Scene model: frozen dataclasses (no GL handles) describing cameras, specimen, speckle,
render options, output and the optional effects. Each checks its own values on construction and
raises :class:`SceneError` naming the key and the fix. Units: millimetres, pixels, degrees for
the stereo angles, radians for ``rvec``. Files are read by :mod:`glsim.scene.load`."""
from __future__ import annotations

import dataclasses
import json
import math
import re
import string
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glsim.scene.camera import Camera, check_ranges
from glsim.errors import SceneError, check
from glsim.limits import (MAX_COORDINATE_MM, MAX_ELEMENTS, MAX_NAME_BYTES, MAX_PIECES, MAX_SAMPLES_PER_PIXEL, MAX_STEPS, check_gl_target, check_image_size,
                          refuse_count, require_file)
from glsim.scene.fields import Field
from glsim.scene.mesh import UNITS_TO_MM
from glsim.scene.tables import Vec3, build, check_length, reject_unknown
from glsim.scene.optional import Exposure, Lighting, Noise, Optics, Psf, Sensor, Vignetting

MODES = ("fast", "q4", "exact")
LATER_TABLES = ("sensor", "psf", "vignetting", "exposure")   # Scene.to_dict leaves them out while absent
LATER_KEYS = {"render": {"pieces": 4}, "specimen": {"field": None}}   # ... and these keys while at their default
INTERPOLATIONS = ("linear", "cubic", "bspline3", "bspline5", "procedural")
BACKENDS = ("gl", "cpu")
PRECISIONS = ("fp32", "fp64")
SUBSAMPLES = ("mapped", "newton")
FORMATS = ("tiff", "png")


GENERATOR_KEYS = ("dot_diameter_px", "density", "oversample", "edge_px", "seed")
_SPECKLE_PLACEMENT = {"centre": (), "u_axis": (1.0, 0.0, 0.0), "normal": ()}


@dataclass(frozen=True)
class Speckle:
    """The reference speckle image and the virtual reference camera that "took" it.

    Either ``image`` (a greyscale file, 8/16-bit or float in [0, 1]) or the built-in
    generator (``image`` empty). The reference camera is ``camera`` if given, otherwise a
    pinhole looking square onto the undeformed specimen at ``mm_per_px`` mm per reference
    pixel; for the generator ``mm_per_px`` defaults to camera 0's scale at the specimen
    divided by ``oversample``.

    Placement without ``camera`` (in the specimen's own frame, mm, before ``specimen.pose``;
    it does not depend on the meshing): the image faces ``normal`` (default: ±Z, the side
    camera 0 is on), its u axis runs along ``u_axis`` (default +X) and v along u_axis ×
    normal (−Y seen from +Z), and its centre pixel sits at ``centre`` ([X, Y] or [X, Y, Z];
    default, and always for the generator: the centre of the undeformed bounding box).
    """
    image: str = ""
    camera: Camera | None = None
    mm_per_px: float = 0.0
    centre: tuple[float, ...] = ()
    u_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    normal: tuple[float, ...] = ()
    dot_diameter_px: float = 5.0   # in camera-0 pixels on the specimen
    density: float = 0.5
    oversample: float = 2.0        # reference pixels per camera-0 pixel
    edge_px: float = 1.0           # width of the dots' smooth edge, camera-0 pixels
    seed: int = 0

    def __post_init__(self):
        if self.image:   # the generator's settings would be ignored without a word
            for f in dataclasses.fields(self):
                if f.name in GENERATOR_KEYS and getattr(self, f.name) != f.default:
                    raise SceneError(f"speckle.{f.name}", f"is a setting of the built-in speckle generator, "
                                     f"which is not used with speckle.image = {self.image!r}",
                                     f"remove {f.name} (the image is used as it is), or remove image to "
                                     f"generate the pattern")
        check(self.mm_per_px >= 0, "speckle.mm_per_px", f"must be ≥ 0, got {self.mm_per_px}",
              "give the reference image scale in mm per pixel (0 = automatic)")
        placed = {k: getattr(self, k) for k in ("centre", "u_axis", "normal")
                  if getattr(self, k) != _SPECKLE_PLACEMENT[k]}
        check(self.camera is None or not placed, f"speckle.{next(iter(placed), 'centre')}",
              "places the image, which speckle.camera already fixes",
              "remove it, or remove speckle.camera")
        check(len(self.centre) in (0, 2, 3), "speckle.centre", f"must have 2 or 3 entries, got {list(self.centre)}",
              "give the image centre in specimen mm, [X, Y] or [X, Y, Z]")
        check_length(self.mm_per_px, "speckle.mm_per_px", "the reference image's scale (mm per pixel)")
        check_length(self.centre or 0.0, "speckle.centre", "the image centre")
        check(not self.centre or bool(self.image), "speckle.centre", "places a speckle.image; the generated "
              "pattern is always centred on the specimen", "remove centre, or give an image")
        check(len(self.normal) in (0, 3), "speckle.normal", f"must have 3 entries, got {list(self.normal)}",
              "the direction the image faces, in the specimen's frame, e.g. [0, 0, 1]")
        for k in ("u_axis", "normal"):
            check(not getattr(self, k) or float(np.linalg.norm(getattr(self, k))) > 0, f"speckle.{k}",
                  "must not be zero", "give a direction in the specimen's frame")
        n = np.asarray(self.normal or (0.0, 0.0, 1.0), float)
        u = np.asarray(self.u_axis, float)
        check(float(np.linalg.norm(np.cross(u, n))) > 1e-6 * float(np.linalg.norm(u) * np.linalg.norm(n)),
              "speckle.u_axis", f"{list(self.u_axis)} is parallel to the image normal {n.tolist()}",
              "give the in-plane direction of the image's u axis")
        check(not self.image or self.camera is not None or self.mm_per_px > 0, "speckle.mm_per_px",
              f"is needed with the reference image file {self.image!r}",
              "give the image scale in mm per pixel, or a speckle.camera table")
        check(self.oversample > 0, "speckle.oversample", f"must be > 0, got {self.oversample}",
              "reference pixels per camera pixel, typically 2–4")
        check(self.dot_diameter_px >= 2.0, "speckle.dot_diameter_px",
              f"must be ≥ 2 px, got {self.dot_diameter_px}",
              "give a diameter of at least 2 camera pixels (smaller dots alias), e.g. 4")
        check(0 <= self.edge_px <= self.dot_diameter_px, "speckle.edge_px",
              f"must lie in [0, dot_diameter_px], got {self.edge_px}",
              "the dots' edge width in camera pixels; ≥ 2 avoids aliasing at 1 sample per pixel")
        check(0 < self.density < 1, "speckle.density", f"must lie in (0, 1), got {self.density}",
              "the covered area fraction, typically 0.5")


@dataclass(frozen=True)
class Plate:
    """Built-in flat rectangular plate in its local XY plane, with rigid translations per step."""
    width: float = 40.0
    height: float = 30.0
    nx: int = 8
    ny: int = 6
    translations: tuple[Vec3, ...] = ()   # one (dx, dy, dz) in mm per load step after step 0

    def __post_init__(self):
        for k in ("width", "height"):
            check(getattr(self, k) > 0, f"specimen.plate.{k}", f"must be > 0, got {getattr(self, k)}",
                  "give it in mm")
            check_length(getattr(self, k), f"specimen.plate.{k}", "the plate's size")
        for k in ("nx", "ny"):
            check(getattr(self, k) >= 1, f"specimen.plate.{k}", f"must be ≥ 1, got {getattr(self, k)}",
                  "the number of elements along that side")
        refuse_count("specimen.plate.nx", self.nx * self.ny, MAX_ELEMENTS, "elements (nx × ny)",
                     "use fewer elements; the plate is flat")
        for i, tr in enumerate(self.translations):
            check(np.shape(tr) == (3,), f"specimen.plate.translations[{i}]", "must have 3 entries",
                  "give [dx, dy, dz] in mm")
            check_length(tr, f"specimen.plate.translations[{i}]", f"load step {i + 1}'s rigid translation")


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
            check(getattr(self, k) > 0, f"specimen.bulge.{k}", f"must be > 0, got {getattr(self, k)}",
                  "give it in mm")
        for k in ("radius", "thickness", "w0"):
            check_length(getattr(self, k), f"specimen.bulge.{k}", f"the bulge's {k}")
        for k in ("steps", "n_core", "n_ring"):
            check(getattr(self, k) >= 1, f"specimen.bulge.{k}", f"must be ≥ 1, got {getattr(self, k)}",
                  "a count")
        refuse_count("specimen.bulge.steps", self.steps, MAX_STEPS, "load steps", "use fewer load steps")
        refuse_count("specimen.bulge.n_core", self.n_core * (self.n_core + 4 * self.n_ring), MAX_ELEMENTS,
                     "elements (n_core² + 4·n_core·n_ring)", "use smaller n_core and n_ring")


EXODUS_SUFFIXES = (".e", ".exo", ".ex2", ".exii", ".g", ".gen")
TIME_SERIES_SUFFIXES = EXODUS_SUFFIXES + (".pvd", ".xdmf", ".xmf")   # XDMF: when it holds a time series


@dataclass(frozen=True)
class MeshFile:
    """An FE mesh file and its steps: read with meshio (Abaqus .inp, VTK/VTU, Gmsh .msh), or a
    time series (Exodus II, ParaView .pvd, XDMF) with one load step per stored time.

    Single-state files: load steps come from at most one of ``point_data``, ``files`` and
    ``csv``. Time series: ``displacement`` names one vector field or the x, y[, z] component
    fields (default: found by the usual names, e.g. disp_x/disp_y/disp_z); ``times`` (the
    file's own time values) or ``steps`` (stored-step indices) select, default all.
    """
    path: str = ""
    unit: str = "mm"
    point_data: tuple[str, ...] = ()   # names of per-step displacement arrays in the file
    files: tuple[str, ...] = ()        # one mesh file per step with a displacement field
    csv: tuple[str, ...] = ()          # one `label;ux;uy;uz` file per step
    field: str = ""                    # displacement field name in `files`
    displacement: str | tuple[str, ...] = ()  # time series: a vector field, or component fields
    times: tuple[float, ...] = ()      # time series: the stored times to render
    steps: tuple[int, ...] = ()        # time series: the stored-step indices to render

    def __post_init__(self):
        check(bool(self.path), "specimen.mesh.path", "is empty", "give the FE mesh file, e.g. 'model.inp'")
        check(self.unit in UNITS_TO_MM, "specimen.mesh.unit", f"unknown unit {self.unit!r}",
              f"use one of {', '.join(UNITS_TO_MM)}")
        sources = [k for k in ("point_data", "files", "csv") if getattr(self, k)]
        check(len(sources) <= 1, f"specimen.mesh.{sources[-1] if sources else ''}",
              f"only one displacement source may be given, got {', '.join(sources)}",
              "keep one of point_data, files, csv")
        check(not self.field or bool(self.files), "specimen.mesh.field", "is only used with files",
              "remove it, or give the per-step files")
        names = (self.displacement,) if isinstance(self.displacement, str) else self.displacement
        check(isinstance(names, (list, tuple)) and len(names) <= 3 and all(isinstance(n, str) for n in names),
              "specimen.mesh.displacement", f"{self.displacement!r} is not 1–3 field names",
              'give a vector field "u" or component fields ["disp_x", "disp_y", "disp_z"]')
        object.__setattr__(self, "displacement", tuple(names))
        check(not (self.times and self.steps), "specimen.mesh.steps", "times and steps both given",
              "keep one of them")
        suffix = Path(self.path).suffix.lower()
        series = [k for k in ("displacement", "times", "steps") if getattr(self, k)]
        check(not series or suffix in TIME_SERIES_SUFFIXES, f"specimen.mesh.{series[0] if series else ''}",
              f"is only used with time-series files, not {suffix or 'this'} files",
              f"give an Exodus II ({', '.join(EXODUS_SUFFIXES)}), .pvd or XDMF time series, or use "
              "point_data, files or csv")
        single = [k for k in ("point_data", "files", "csv", "field") if getattr(self, k)]
        check(not single or suffix not in EXODUS_SUFFIXES + (".pvd",), f"specimen.mesh.{single[0] if single else ''}",
              f"is for single-state files; {suffix} files hold their own time steps",
              "use displacement = [...] and times or steps instead")


@dataclass(frozen=True)
class Specimen:
    """The FE specimen: one source (``mesh``, ``plate`` or ``bulge``) and its placement.

    Placement maps specimen coordinates to the world (camera 0's frame by default):
    X_world = R·X + t, mm. In a scene file it is the ``pose`` table (R or rvec, and t).
    ``field``: a displacement field added to the load steps (:mod:`glsim.scene.fields`).
    """
    mesh: MeshFile | None = None
    plate: Plate | None = None
    bulge: Bulge | None = None
    R: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    t: tuple = (0.0, 0.0, 0.0)
    field: Field | None = None

    def __post_init__(self):
        given = [k for k in ("mesh", "plate", "bulge") if getattr(self, k) is not None]
        check(len(given) == 1, "specimen",
              f"exactly one of mesh, plate, bulge must be given, got {', '.join(given) or 'none'}",
              "keep one of [specimen.bulge], [specimen.plate], [specimen.mesh] path = 'model.inp'")
        check_length(self.t, "specimen.pose.t", "the specimen's placement")
        check(self.field is None or isinstance(self.field, Field), "specimen.field",
              f"expected a table, got {self.field!r}", "write [specimen.field] with random, affine, bumps, … tables")


@dataclass(frozen=True)
class Render:
    """How images are made. ``samples_per_pixel`` is a square (1, 4, 9, 16, …): box filter."""
    backend: str = "gl"
    mode: str = "exact"
    interpolation: str = "bspline3"
    samples_per_pixel: int = 1
    background: float = 0.0       # grey level in [0, 1] of full scale
    precision: str = "fp64"       # GL arithmetic of the exact mode's intersection
    # exact mode, samples_per_pixel > 1, GL: every sub-sample mapped on its own ray ("mapped"),
    # or placed by Newton steps from its pixel centre's mapping ("newton", shaders/subsamples.frag;
    # the CPU oracle maps every sample)
    subsamples: str = "mapped"
    # quadratic elements: the linear pieces per element side that the fast mode draws (its error
    # falls as 1/pieces², docs/quadratic.md) and GL's covers and candidate lists are made of
    pieces: int = LATER_KEYS["render"]["pieces"]

    def __post_init__(self):
        for key, allowed in (("backend", BACKENDS), ("mode", MODES), ("interpolation", INTERPOLATIONS),
                             ("precision", PRECISIONS), ("subsamples", SUBSAMPLES)):
            value = getattr(self, key)
            check(value in allowed, f"render.{key}", f"{value!r} is not one of {allowed}",
                  f"use one of {', '.join(allowed)}")
        spp = self.samples_per_pixel
        check(isinstance(spp, (int, np.integer)) and not isinstance(spp, bool) and spp >= 1
              and math.isqrt(spp) ** 2 == spp, "render.samples_per_pixel",
              f"must be a perfect square ≥ 1, got {spp!r}", "use 1, 4, 9, 16, …")
        refuse_count("render.samples_per_pixel", spp, MAX_SAMPLES_PER_PIXEL, "samples per pixel",
                     "use 1, 4, 9, 16, … (16 is usually plenty)")
        check(0.0 <= self.background <= 1.0, "render.background",
              f"must lie in [0, 1], got {self.background}", "a fraction of full scale")
        n = self.pieces
        check(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= MAX_PIECES,
              "render.pieces", f"must be an integer in 1…{MAX_PIECES}, got {n!r}",
              "the fast mode's linear pieces per quadratic element side: its error falls as 1/pieces², "
              "e.g. 4 (the default) or 8")

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
        check(self.format in FORMATS, "output.format", f"{self.format!r} is not one of {FORMATS}",
              "use 'tiff' (8/16-bit) or 'png'")
        why = _pattern_problem(self.pattern)
        check(not why, "output.pattern", f"{_shown(self.pattern)} {why}",
              f"use only the fields {{camera}}, {{step}} and {{ext}}, with widths of at most {MAX_NAME_BYTES}, e.g. "
              "'{camera}_{step:04d}.{ext}'")
        try:
            names = {self.pattern.format(camera=c, step=k, ext="tif") for c in ("cam0", "cam1") for k in (0, 1)}
        except (KeyError, IndexError, ValueError) as exc:
            raise SceneError("output.pattern", f"{self.pattern!r} cannot be formatted ({exc!r})",
                             "use only the fields {camera}, {step} and {ext}") from None
        check(len(names) == 4, "output.pattern", f"{self.pattern!r} gives two images the same file name",
              "include both {camera} and {step}, e.g. '{camera}_{step:04d}.{ext}'")
        longest = self.pattern.format(camera="c" * NAME_MAX, step=0, ext="tiff")
        for name in sorted(names) + [longest]:
            why = _outside(name)
            check(not why, "output.pattern", f"{_shown(self.pattern)} gives {_shown(name)}, which {why}",
                  "give names relative to the output directory: subfolders as 'a/b', no '..', no leading '/' or "
                  "'.', no backslash or control character, e.g. '{camera}_{step:04d}.{ext}'")


def _pattern_problem(pattern: str) -> str:
    """Why ``pattern`` cannot be formatted safely ("" if it can): checked before it is formatted,
    so that no format spec allocates more than a file name holds (``{step:2000000000}``)."""
    try:
        fields = [(f, spec) for _, f, spec, _ in string.Formatter().parse(pattern) if f is not None]
    except ValueError as exc:
        return f"cannot be formatted ({exc})"
    for name, spec in fields:
        if name not in ("camera", "step", "ext"):
            return f"has the field {{{name}}}" if name else "has an unnamed field {}"
        if "{" in spec:
            return f"nests a field in the format of {{{name}:{spec[:20]}}}"
        wide = [d for d in re.findall(r"[1-9]\d*", spec) if len(d) > 3 or int(d) > MAX_NAME_BYTES]
        if wide:
            return (f"asks for {_shown(wide[0], 12)[1:-1]} characters in {{{name}:{_shown(spec, 20)[1:-1]}}}, more "
                    f"than a file name holds ({MAX_NAME_BYTES} bytes)")
    return ""


def check_output_names(pattern: str, files) -> None:
    """SceneError("output.pattern") if two of ``files`` — (file name relative to the output
    directory, what it holds) pairs: every file a render writes, its images named by ``pattern``
    for the scene's real cameras and steps — have the same name, or a name would leave (or hide in)
    the output directory."""
    seen = {}
    for name, what in files:
        why = _outside(name)
        check(not why, "output.pattern", f"{_shown(pattern)} gives {_shown(name)} for {what}, which {why}",
              "give names relative to the output directory: subfolders as 'a/b', no '..', no leading '/' or "
              "'.', no backslash or control character, e.g. '{camera}_{step:04d}.{ext}'")
        if name in seen:
            raise SceneError("output.pattern", f"{_shown(pattern)} gives {seen[name]} and {what} the same file name "
                             f"{_shown(name)}", "include both {camera} and {step} in full, e.g. "
                             "'{camera}_{step:04d}.{ext}' (a format such as {step:.0e} or {camera:.4} cuts them)")
        seen[name] = what


NAME_MAX = 64
_NAME = re.compile(rf"[A-Za-z0-9_-][A-Za-z0-9_.-]{{0,{NAME_MAX - 1}}}")


def _outside(name: str) -> str:
    """Why the relative file name ``name`` could leave (or hide in) the output directory; "" if not."""
    bad = next((ch for ch in name if ch < " " or ch in "\\\x7f"), None)
    if bad is not None:
        return f"contains {bad!r}"
    if name.startswith("/"):
        return "is an absolute path"
    part = next((p for p in name.split("/") if not p or p.startswith(".")), None)
    if part is not None:
        return {"": "has an empty part", "..": "has the part '..', which leaves the output directory"}.get(
            part, f"has the hidden name {_shown(part)}")
    longest = max(len(p.encode()) for p in name.split("/"))
    return f"has a part of {longest} bytes (at most 255)" if longest > 255 else ""


def _shown(value, width: int = 48) -> str:
    """``repr(value)``, cut to ``width`` characters."""
    text = repr(value)
    return text if len(text) <= width else text[:width - 2] + "…'"


def _check_name(name, key: str) -> None:
    """``name`` ends up in file names: it must be plain (see ``_NAME``)."""
    if isinstance(name, str) and _NAME.fullmatch(name):
        return
    if not isinstance(name, str):
        why = "is not a string"
    elif len(name) > NAME_MAX:
        why = f"is {len(name)} characters long"
    elif not name:
        why = "is empty"
    else:
        bad = next((ch for ch in name if not _NAME.fullmatch("a" + ch)), None)
        why = f"contains {bad!r}" if bad else "starts with '.'"
    raise SceneError(key, f"{_shown(name)} cannot name files: it {why}",
                     f"use 1–{NAME_MAX} letters, digits, '_', '-' or '.' (not first), e.g. 'cam0'")


@dataclass(frozen=True)
class Scene:
    """A whole virtual stereo-DIC experiment. ``base_dir`` resolves relative file paths."""
    cameras: tuple[Camera, ...]
    specimen: Specimen = field(default_factory=lambda: Specimen(bulge=Bulge()))
    speckle: Speckle = field(default_factory=Speckle)
    render: Render = field(default_factory=Render)
    output: Output = field(default_factory=Output)
    lighting: Lighting | None = None   # None: no lighting code runs
    optics: Optics | None = None       # None: infinite depth of field, no blur pass
    noise: Noise | None = None         # None: noise-free
    exposure: Exposure | None = None   # None: an instantaneous exposure, nothing moves during it
    sensor: Sensor | None = None       # None: full fill factor, no fixed-pattern noise
    psf: Psf | None = None             # None: no lens PSF pass
    vignetting: Vignetting | None = None   # None: no fall-off
    seed: int = 0
    base_dir: str = "."

    def __post_init__(self):
        check(len(self.cameras) >= 1, "cameras", "at least one camera is needed",
              "add a [[cameras]] table")
        names = [c.name for c in self.cameras]
        for i, name in enumerate(names):
            _check_name(name, f"cameras[{i}].name")
            check(name not in names[:i], f"cameras[{i}].name",
                  f"{name!r} is already the name of cameras[{names.index(name)}]",
                  "give each camera a unique name")
        self._check_sizes()
        for i, cam in enumerate(self.cameras):
            check_ranges(cam, f"cameras[{i}]")
        if self.speckle.camera is not None:
            check_ranges(self.speckle.camera, "speckle.camera")
        self._check_motion()
        check(self.sensor is None or self.sensor.fill_factor == 1 or self.render.mode != "fast"
              or self.render.samples_per_pixel == 1, "sensor.fill_factor",
              f"{self.sensor and self.sensor.fill_factor} needs samples placed inside each pixel, which mode 'fast' "
              "(the rasterizer's fixed sample grid) cannot do", "use render.mode = 'exact' or 'q4', or fill_factor = 1")
        files = {"speckle.image": self.speckle.image} if self.speckle.image else {}
        if self.noise is not None and self.noise.variance_file:
            files["noise.variance_file"] = self.noise.variance_file
        if self.psf is not None and self.psf.image:
            files["psf.image"] = self.psf.image
        mesh = self.specimen.mesh
        if mesh is not None:
            files["specimen.mesh.path"] = mesh.path
            files.update({f"specimen.mesh.files[{i}]": p for i, p in enumerate(mesh.files)})
            files.update({f"specimen.mesh.csv[{i}]": p for i, p in enumerate(mesh.csv)})
        for key, path in files.items():
            require_file(self.resolve(path), key, "check the path (relative paths start at the scene file's directory)")

    def _check_motion(self) -> None:
        """A rolling shutter needs a motion to skew."""
        rolling = self.sensor is not None and self.sensor.line_time > 0
        check(not rolling or self.exposure is not None, "sensor.line_time",
              "delays each row, but the scene gives no motion to expose it at",
              "add an [exposure] table (velocity, or load steps to interpolate between), or remove line_time")
        ex = self.exposure
        if ex is not None and ex.velocity is not None:   # the farthest a rigid motion carries the specimen
            rows = max(c.height for c in self.cameras) - 1
            tau = ex.time / 2 + (rows / 2 * self.sensor.line_time if rolling else 0.0)
            moved = float(np.abs(ex.velocity).max()) * tau
            check(moved <= MAX_COORDINATE_MM, "exposure.velocity", f"{list(ex.velocity)} mm/s moves the specimen "
                  f"{moved:.3g} mm within the exposure, beyond glsim's limit of {MAX_COORDINATE_MM:g} mm",
                  "give the velocity in mm/s and the exposure time in s")

    def _check_sizes(self) -> None:
        """Image sizes against glsim's limits (:mod:`glsim.limits`), and a speckle dot camera 0 can show."""
        cams = [(f"cameras[{i}].size", c) for i, c in enumerate(self.cameras)]
        if self.speckle.camera is not None:
            cams.append(("speckle.camera.size", self.speckle.camera))
        for key, cam in cams:
            check_image_size(key, cam.width, cam.height, "the image", "give a smaller size")
        for key, cam in cams[:len(self.cameras)]:   # GL renders at W·√spp × H·√spp; the CPU oracle in chunks
            if self.render.backend == "gl":
                check_gl_target("render.samples_per_pixel", cam.size, self.render.samples_per_pixel)
        first = self.cameras[0]
        check(self.speckle.image or self.speckle.dot_diameter_px <= min(first.size), "speckle.dot_diameter_px",
              f"{self.speckle.dot_diameter_px:g} px is larger than camera {first.name}'s image ({first.width} × "
              f"{first.height} px): the pattern would be one blank dot", "give dots of 3–10 px, e.g. 5")

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
        reject_unknown(sections, [f.name for f in dataclasses.fields(self)], "")
        changes = {}
        for name, value in sections.items():
            current = getattr(self, name)
            if isinstance(value, dict) and current is None:   # an effect switched on
                value = build(typing.get_type_hints(Scene)[name].__args__[0], value, name)
            elif isinstance(value, dict):
                reject_unknown(value, [f.name for f in dataclasses.fields(current) if f.init], name)
                value = dataclasses.replace(current, **value)
            changes[name] = value
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The resolved scene (every default filled) as plain JSON-able data. Tables added since
        the first release (:data:`LATER_TABLES`) are left out while absent, and keys added to
        tables since (:data:`LATER_KEYS`) while at their default, so the scene.json of a scene
        that does not use them — what a render directory is resumed by — and the fingerprints
        made from it stay as they were."""
        d = _plain(dataclasses.asdict(self))
        d.update({table: recorded(table, d[table]) for table in LATER_KEYS})
        return {k: v for k, v in d.items() if not (k in LATER_TABLES and v is None)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


def recorded(table: str, values: dict) -> dict:
    """A table's values as records hold them: without its :data:`LATER_KEYS` at their default."""
    later = LATER_KEYS.get(table, {})
    return {k: v for k, v in values.items() if not (k in later and v == later[k])}


def _plain(obj):
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj
