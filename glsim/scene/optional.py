"""The scene's optional tables, each absent by default (a scene without one runs none of its
code): lighting and its lights, optics (depth of field), noise, and the camera beyond the paper —
sensor, lens PSF, vignetting, exposure. Frozen dataclasses that check their own values and raise
:class:`SceneError` naming the key and the fix."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glsim.errors import check
from glsim.limits import refuse_count
from glsim.scene.tables import Vec3, check_length


LIGHT_COMBINE = ("additive", "multiplicative")
NORMALS = ("smooth", "flat")
KERNELS = ("gaussian", "disk")
BLUR_SCHEMES = ("auto", "expansion", "gather", "hybrid", "separable")
NOISE_MODELS = ("gaussian", "heteroscedastic", "poisson_gaussian")


def _one_of(obj, key: str, name: str, allowed) -> None:
    value = getattr(obj, name)
    check(value in allowed, f"{key}.{name}", f"{value!r} is not one of {allowed}",
          f"use one of {', '.join(allowed)}")


@dataclass(frozen=True)
class Light:
    """A point light, or a spotlight when ``direction`` is given (world frame, mm).

    ``intensity`` I_i in fraction of full scale (the paper's Table 1, 80 grey levels of an
    8-bit camera, is 80/255); ``attenuation`` k of 1/(1 + k d²) in 1/mm²; ``cutoff`` the
    spot's half-angle and ``edge`` the width of its smooth edge inside the cutoff, degrees.
    """
    position: Vec3
    intensity: float = 0.3
    attenuation: float = 0.0
    direction: Vec3 | None = None
    cutoff: float = 180.0
    edge: float = 0.0

    def __post_init__(self):
        check(0 < self.cutoff <= 180, "cutoff", f"must lie in (0, 180] degrees, got {self.cutoff}",
              "the spotlight's half-angle")
        check(0 <= self.edge <= self.cutoff, "edge", f"must lie in [0, cutoff], got {self.edge}",
              "the smooth edge's width in degrees")
        check(self.attenuation >= 0, "attenuation", "must be ≥ 0", "k of 1/(1 + k d²), 1/mm²")
        check(self.direction is None or np.linalg.norm(self.direction) > 0, "direction",
              "must not be zero", "give the spotlight's axis, or leave it out for a point light")


@dataclass(frozen=True)
class Lighting:
    """Phong reflection (paper eqs. 10–13) combined with the speckle grey level.

    ``combine = "additive"``: grey + I (the paper's model, grey levels added);
    ``"multiplicative"``: grey × I (albedo × irradiance; I = 1 is the unlit brightness).
    ``normals = "smooth"``: vertex normals averaged over adjacent elements and interpolated
    (the paper's adapted Gouraud); ``"flat"``: one normal per element.
    """
    ambient: float = 0.0
    lights: tuple[Light, ...] = ()
    diffuse: float = 1.0
    specular: float = 0.0
    shininess: float = 1.0
    normals: str = "smooth"
    combine: str = "additive"

    def __post_init__(self):
        _one_of(self, "lighting", "normals", NORMALS)
        _one_of(self, "lighting", "combine", LIGHT_COMBINE)
        check(self.shininess > 0, "lighting.shininess", "must be > 0", "the Phong exponent r")


@dataclass(frozen=True)
class Optics:
    """Lens and aperture for depth of field (paper eqs. 14–19), mm.

    ``focus_distance`` is measured along the optical axis (a point's distance is its
    camera-frame depth); ``coc_px`` is the acceptable circle of confusion in pixels.
    ``scheme`` is how the GL backend evaluates the Gaussian gather (the CPU oracle always
    gathers exactly in 2-D): ``expansion`` (``auto``'s choice), ``gather``, ``hybrid`` or
    ``separable``; the disk kernel is always gathered in 2-D (``auto`` or ``gather``).
    """
    focal_length: float
    f_number: float
    focus_distance: float
    pixel_pitch: float
    coc_px: float = 1.0
    kernel: str = "gaussian"
    scheme: str = "auto"

    def __post_init__(self):
        for name in ("focal_length", "f_number", "pixel_pitch", "coc_px"):
            check(getattr(self, name) > 0, f"optics.{name}", f"must be > 0, got {getattr(self, name)}",
                  "give a positive value")
        for name in ("focal_length", "focus_distance", "pixel_pitch"):
            check_length(getattr(self, name), f"optics.{name}", f"the {name.replace('_', ' ')}")
        check(self.focus_distance > self.focal_length, "optics.focus_distance",
              f"must exceed the focal length ({self.focal_length} mm), got {self.focus_distance}",
              "the focused distance in mm")
        _one_of(self, "optics", "kernel", KERNELS)
        _one_of(self, "optics", "scheme", BLUR_SCHEMES)
        check(self.kernel == "gaussian" or self.scheme in ("auto", "gather"), "optics.scheme",
              f"{self.scheme!r} applies to the Gaussian kernel only (the disk is not separable)",
              "use scheme = 'auto' or 'gather' with kernel = 'disk'")


@dataclass(frozen=True)
class Noise:
    """Sensor noise before quantisation (paper §2.2.3 and beyond).

    ``gaussian``: σ = ``sigma`` % of the dynamic range; ``heteroscedastic``: variance per
    grey level (DN, DN²) from the CSV ``variance_file``; ``poisson_gaussian``: shot noise of
    I·``full_well`` electrons plus ``read_noise`` electrons rms.
    """
    model: str = "gaussian"
    sigma: float = 0.0
    variance_file: str = ""
    full_well: float = 10000.0
    read_noise: float = 0.0

    def __post_init__(self):
        _one_of(self, "noise", "model", NOISE_MODELS)
        check(self.sigma >= 0, "noise.sigma", "must be ≥ 0", "percent of the dynamic range, e.g. 2")
        check(self.full_well > 0 and self.read_noise >= 0, "noise.full_well",
              "full_well must be > 0 and read_noise ≥ 0", "electrons")
        check(self.model != "heteroscedastic" or bool(self.variance_file), "noise.variance_file",
              "is required by the heteroscedastic model", "give a CSV of grey level;variance")


PSF_KINDS = ("gaussian", "airy", "image")


@dataclass(frozen=True)
class Psf:
    """The lens point-spread function, convolved with the irradiance after pixel integration and
    depth of field, before noise (docs/camera.md). ``gaussian``: σ = ``sigma`` px; ``airy``: the
    diffraction-limited disk of ``wavelength_nm`` at ``f_number`` on pixels of ``pixel_pitch`` mm
    (first zero at 1.22·λ·N); ``image``: a measured PSF file sampled in px (odd sides, centred;
    normalised to sum 1). Boundary: clamp to edge."""
    kind: str = "gaussian"
    sigma: float = 0.0
    wavelength_nm: float = 550.0
    f_number: float = 0.0
    pixel_pitch: float = 0.0
    image: str = ""

    def __post_init__(self):
        _one_of(self, "psf", "kind", PSF_KINDS)
        given = {"gaussian": ("sigma",), "airy": ("f_number", "pixel_pitch"), "image": ("image",)}[self.kind]
        for name in ("sigma", "f_number", "pixel_pitch", "image"):
            value = getattr(self, name)
            if name in given:
                check(bool(value) and (name == "image" or value > 0), f"psf.{name}",
                      f"must be {'given' if name == 'image' else '> 0'} for kind = {self.kind!r}, got {value!r}",
                      {"sigma": "the Gaussian's σ in px, e.g. 0.8", "f_number": "the aperture's f-number, e.g. 8",
                       "pixel_pitch": "the pixel pitch in mm, e.g. 0.0055",
                       "image": "a greyscale PSF file (odd sides, PSF centred), e.g. 'psf.tif'"}[name])
            else:
                check(not value, f"psf.{name}", f"is not used by kind = {self.kind!r}",
                      "remove it, or choose the kind that uses it")
        check(self.wavelength_nm > 0, "psf.wavelength_nm", f"must be > 0, got {self.wavelength_nm}",
              "the light's wavelength in nm, e.g. 550")


@dataclass(frozen=True)
class Vignetting:
    """Fall-off of the irradiance towards the image corners, a gain per pixel (docs/camera.md):
    ``natural`` cos⁴ of the chief-ray angle (from the camera model's undistorted ray), times
    ``1 + radial[0]·r² + radial[1]·r⁴ + …`` (r: the normalized radius of that ray);
    ``flat_field``: ``glsim render`` also writes each camera's gain image."""
    natural: bool = False
    radial: tuple[float, ...] = ()
    flat_field: bool = False

    def __post_init__(self):
        check(self.natural or bool(self.radial), "vignetting.natural", "neither natural nor radial is given",
              "set natural = true (cos⁴) and/or radial = [a1, a2, …], or remove [vignetting]")


@dataclass(frozen=True)
class Sensor:
    """The pixel array (EMVA 1288 terms). ``fill_factor`` (0, 1]: the active share of each pixel,
    a centred square over which its samples lie; ``prnu``: photo-response non-uniformity, the
    per-pixel gain's σ in % of the signal; ``dsnu``: dark-signal non-uniformity, the per-pixel
    offset's σ in DN. Both patterns are fixed per camera (seeded by the scene seed and the
    camera, not the step)."""
    fill_factor: float = 1.0
    prnu: float = 0.0
    dsnu: float = 0.0
    line_time: float = 0.0   # s per row: a rolling shutter (0: global), docs/motion.md

    def __post_init__(self):
        check(0 < self.fill_factor <= 1, "sensor.fill_factor", f"must lie in (0, 1], got {self.fill_factor}",
              "the active fraction of the pixel area, e.g. 0.5 (1: the whole pitch)")
        check(0 <= self.prnu <= 100, "sensor.prnu", f"must lie in [0, 100] %, got {self.prnu}",
              "the gain non-uniformity σ in % of the signal, e.g. 1")
        check(self.dsnu >= 0, "sensor.dsnu", f"must be ≥ 0, got {self.dsnu}",
              "the dark offset non-uniformity σ in DN, e.g. 2")
        check(math.isfinite(self.line_time) and self.line_time >= 0, "sensor.line_time",
              f"must be ≥ 0 s, got {self.line_time}", "the rolling shutter's row-to-row delay in s, e.g. 1e-5 "
              "(0: a global shutter); row r is exposed around t_step + (r − (H − 1)/2)·line_time")


MAX_EXPOSURE_SAMPLES = 1024   # exposure.samples: renders averaged per image


@dataclass(frozen=True)
class Exposure:
    """Motion over the exposure (docs/motion.md): the image averages the irradiance over ``time``
    seconds centred on the load step's time, sampled at ``samples`` instants (midpoint rule).

    The specimen moves rigidly when ``velocity`` (mm/s) or ``angular_velocity`` (rad/s, a
    rotation vector about ``centre``, mm; default the step's node centroid) is given, world frame;
    otherwise its state is interpolated linearly in time between load steps, at the FE file's
    solver times where it has them, else at ``step_time`` seconds per step (step k at k·step_time),
    and held before the first and after the last step.
    """
    time: float = 0.0
    samples: int = 1
    velocity: Vec3 | None = None
    angular_velocity: Vec3 | None = None
    centre: Vec3 | None = None
    step_time: float = 1.0

    def __post_init__(self):
        check(math.isfinite(self.time) and self.time >= 0, "exposure.time", f"must be ≥ 0 s, got {self.time}",
              "give the exposure time in seconds, e.g. 0.001")
        n = self.samples
        check(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1, "exposure.samples",
              f"must be an integer ≥ 1, got {n!r}", "give the time samples averaged over the exposure, e.g. 8")
        refuse_count("exposure.samples", n, MAX_EXPOSURE_SAMPLES, "renders per image", "use fewer samples")
        check(n == 1 or self.time > 0, "exposure.samples", f"{n} samples of an instantaneous exposure (time = 0)",
              "give exposure.time > 0, or samples = 1")
        check(math.isfinite(self.step_time) and self.step_time > 0, "exposure.step_time",
              f"must be > 0 s, got {self.step_time}", "the seconds between load steps without solver times")
        for k in ("velocity", "angular_velocity", "centre"):
            v = getattr(self, k)
            check(v is None or (np.shape(v) == (3,) and bool(np.isfinite(v).all())), f"exposure.{k}",
                  f"must be 3 finite numbers, got {v!r}", "give [x, y, z] in the world frame")
        if self.centre is not None:
            check_length(self.centre, "exposure.centre", "the rotation's centre")
        check(self.centre is None or self.angular_velocity is not None, "exposure.centre",
              "is the centre of a rotation, but angular_velocity is not given",
              "give angular_velocity (rad/s), or remove centre")
        check(not self.rigid or self.step_time == 1.0, "exposure.step_time",
              "times the load steps, which a rigid motion (velocity, angular_velocity) does not interpolate",
              "remove step_time, or remove velocity and angular_velocity")

    @property
    def rigid(self) -> bool:
        """Whether the specimen moves rigidly (else between load steps)."""
        return self.velocity is not None or self.angular_velocity is not None


def rigid_state(X: np.ndarray, tau: float, velocity: np.ndarray, omega: np.ndarray | None,
                centre: np.ndarray) -> np.ndarray:
    """Points X (…, 3) mm of a rigid motion τ s on (:class:`Exposure`, world frame):
    c + R(ωτ)·(X − c) + v·τ, R the rotation by the vector ωτ (``omega`` None: none)."""
    if omega is not None:
        from glsim.scene.camera import rodrigues

        X = (X - centre) @ rodrigues(omega * tau).T + centre
    return X + velocity * tau


def motion_centre(exposure: "Exposure", mesh, step: int) -> np.ndarray:
    """The centre (3,) mm of ``exposure``'s rotation at ``step`` of FE ``mesh``: the given
    ``centre``, else the centroid of the nodes its elements use at that step (a quadratic
    mesh's mid-side and centre nodes too)."""
    if exposure.centre is not None:
        return np.asarray(exposure.centre, np.float64)
    used = np.unique(mesh.patches[mesh.patches >= 0]) if mesh.is_quadratic else np.unique(mesh.quads)
    return np.asarray(mesh.deformed(step)[used].mean(axis=0), np.float64)


def row_offsets(height: int, line_time: float) -> np.ndarray:
    """A rolling shutter's rows' exposure centres (H,) s from the step's time (``line_time`` s
    per row, :class:`Sensor`): the middle row at 0."""
    return (np.arange(height) - (height - 1) / 2) * line_time
