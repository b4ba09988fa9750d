"""Calibration targets as glsim specimens: a flat plate mesh plus an exactly antialiased
reference image of the target and the fronto-parallel pinhole that maps the plate onto it.

The target frame (mm): origin at the centre of the plate, x along the columns (to the right as
printed), y along the rows (down as printed), z into the plate, so a camera that looks at the
printed face sees x right and y down. Dot (row i, col j) sits nominally at
((j − (cols − 1)/2)·pitch, (i − (rows − 1)/2)·pitch, 0); points are numbered row-major.

Reference images are drawn with exact area coverage: a pixel's grey is background +
(dot − background) × (the exact area of the pixel square covered by the dot), so every
dot's area is exact and its reference-image centroid is its centre to within the pixel-centre
quadrature of a sharp disc ("pixel locking": measured ≤ 6e-4 reference px for dots of 20 px
radius at random sub-pixel positions, i.e. < 0.1 µm at 8 px/mm; tests/test_calib.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from glsim.scene import mesh as meshmod
from glsim.scene.camera import Camera
from glsim.errors import check
from glsim.imaging.reference import Reference

REF_DISTANCE = 1000.0   # mm from the reference pinhole to the plate in its canonical position
PAD_PX = 4              # reference-image border beyond the plate, background grey


@dataclass(frozen=True)
class Defects:
    """Manufacturing errors of a dot grid: the true centre of every dot is

    nominal·(1 + pitch_error) + N(0, sigma²) per coordinate (mm, seeded by ``seed``).
    The nominal grid is what a calibration is told; the true one is what is printed.
    """
    sigma: float = 0.0          # mm, standard deviation of each in-plane coordinate
    pitch_error: float = 0.0    # relative, e.g. 1e-4 = +1 µm per 10 mm
    seed: int = 0

    def __post_init__(self):
        check(self.sigma >= 0 and math.isfinite(self.sigma), "target.defects.sigma",
              f"must be a finite number ≥ 0, got {self.sigma}", "give the dot-centre scatter in mm")
        check(abs(self.pitch_error) < 0.1, "target.defects.pitch_error",
              f"must lie in (−0.1, 0.1), got {self.pitch_error}", "give a relative error, e.g. 1e-4")


@dataclass(frozen=True)
class DotGrid:
    """A rows × cols dot grid (mm, grey levels in [0, 1] of full scale).

    ``markers``: (row, col) cells whose dots have ``marker_diameter`` instead of
    ``dot_diameter``; they fix the grid's orientation (a square grid is otherwise the same
    after a 90° turn). None places three near the centre in an L that no rotation maps onto
    itself; () gives no markers. ``margin``: plate border beyond the outer dot centres.
    ``px_per_mm``: reference-image resolution.
    """
    rows: int = 9
    cols: int = 9
    pitch: float = 10.0
    dot_diameter: float = 5.0
    dot_grey: float = 0.85
    background_grey: float = 0.15
    markers: tuple[tuple[int, int], ...] | None = None
    marker_diameter: float = 3.0
    margin: float = 10.0
    px_per_mm: float = 10.0
    defects: Defects = field(default_factory=Defects)

    def __post_init__(self):
        for key in ("rows", "cols"):
            v = getattr(self, key)
            check(isinstance(v, int) and v >= 3, f"target.{key}", f"must be an integer ≥ 3, got {v!r}",
                  "findCirclesGrid needs at least 3 × 3 dots")
        for key in ("pitch", "dot_diameter", "marker_diameter", "px_per_mm"):
            v = getattr(self, key)
            check(v > 0, f"target.{key}", f"must be > 0, got {v}", "give it in mm (px_per_mm: px per mm)")
        for key in ("dot_diameter", "marker_diameter"):
            check(getattr(self, key) <= 0.7 * self.pitch, f"target.{key}",
                  f"{getattr(self, key)} mm leaves too little gap at pitch {self.pitch} mm",
                  "keep dots ≤ 0.7 × pitch (detection windows span ±0.45 pitch)")
        check(self.margin >= 0.5 * self.pitch, "target.margin", f"must be ≥ pitch/2, got {self.margin}",
              "leave a border of at least half a pitch around the outer dots")
        check(abs(self.dot_grey - self.background_grey) >= 0.1, "target.dot_grey",
              f"contrast {abs(self.dot_grey - self.background_grey):.3g} is below 0.1",
              "make dot_grey and background_grey differ by ≥ 0.1 of full scale")
        for key in ("dot_grey", "background_grey"):
            v = getattr(self, key)
            check(0 <= v <= 1, f"target.{key}", f"must lie in [0, 1], got {v}", "a fraction of full scale")
        markers = _default_markers(self.rows, self.cols) if self.markers is None else \
            tuple((int(r), int(c)) for r, c in self.markers)
        for r, c in markers:
            check(0 <= r < self.rows and 0 <= c < self.cols, "target.markers",
                  f"cell ({r}, {c}) is outside the {self.rows} × {self.cols} grid", "give (row, col) cells")
        check(not markers or len(symmetries(self.rows, self.cols, markers)) == 1, "target.markers",
              f"{markers} look the same after a turn of the grid", "use an L of three cells, e.g. "
              "((r, c), (r, c + 1), (r + 2, c))")
        check(not markers or abs(self.marker_diameter - self.dot_diameter) >= 0.2 * self.dot_diameter,
              "target.marker_diameter", "is too close to dot_diameter to tell markers apart",
              "make it differ by ≥ 20 %, e.g. 0.6 × dot_diameter")
        object.__setattr__(self, "markers", markers)

    @property
    def white_dots(self) -> bool:
        return self.dot_grey > self.background_grey

    @property
    def size(self) -> tuple[float, float]:
        """Plate (width, height), mm."""
        return ((self.cols - 1) * self.pitch + 2 * self.margin, (self.rows - 1) * self.pitch + 2 * self.margin)

    @property
    def n_points(self) -> int:
        return self.rows * self.cols

    def points(self) -> np.ndarray:
        """Nominal dot centres (N, 3) in the target frame, mm, row-major."""
        i, j = np.divmod(np.arange(self.n_points), self.cols)
        return np.stack([(j - (self.cols - 1) / 2) * self.pitch, (i - (self.rows - 1) / 2) * self.pitch,
                         np.zeros(self.n_points)], axis=1)

    def true_points(self) -> np.ndarray:
        """Printed dot centres (N, 3), mm: :meth:`points` with the :class:`Defects` applied."""
        d = self.defects
        p = self.points() * (1.0 + d.pitch_error)
        p[:, :2] += np.random.default_rng(d.seed).normal(0.0, d.sigma, (self.n_points, 2)) if d.sigma else 0.0
        return p

    def diameters(self) -> np.ndarray:
        """Dot diameters (N,), mm."""
        out = np.full(self.n_points, self.dot_diameter)
        for r, c in self.markers:
            out[r * self.cols + c] = self.marker_diameter
        return out

    def draw(self) -> np.ndarray:
        """The reference image, float32 (H, W), centred on the target origin at ``px_per_mm``."""
        image = np.full(_ref_shape(self), self.background_grey, np.float64)
        H, W = image.shape
        s = self.px_per_mm
        for (x, y, _), d in zip(self.true_points(), self.diameters()):
            uc, vc, r = (W - 1) / 2 + x * s, (H - 1) / 2 + y * s, d / 2 * s
            u0, u1 = int(math.floor(uc - r)), int(math.ceil(uc + r)) + 1
            v0, v1 = int(math.floor(vc - r)), int(math.ceil(vc + r)) + 1
            u, v = np.meshgrid(np.arange(u0, u1) - uc, np.arange(v0, v1) - vc)
            image[v0:v1, u0:u1] += (self.dot_grey - self.background_grey) * disc_coverage(u, v, r)
        return image.astype(np.float32)


@dataclass(frozen=True)
class Chessboard:
    """A chessboard of rows × cols squares (``square`` mm); its points are the
    (rows − 1) × (cols − 1) inner corners, row-major. The top-left square is dark."""
    rows: int = 7
    cols: int = 10
    square: float = 10.0
    dark_grey: float = 0.1
    light_grey: float = 0.9
    margin: float = 10.0
    px_per_mm: float = 10.0

    def __post_init__(self):
        for key in ("rows", "cols"):
            check(isinstance(getattr(self, key), int) and getattr(self, key) >= 3, f"target.{key}",
                  f"must be an integer ≥ 3, got {getattr(self, key)!r}", "count squares, not corners")
        for key in ("square", "px_per_mm", "margin"):
            check(getattr(self, key) > 0, f"target.{key}", f"must be > 0, got {getattr(self, key)}", "give it in mm")

    @property
    def size(self) -> tuple[float, float]:
        return (self.cols * self.square + 2 * self.margin, self.rows * self.square + 2 * self.margin)

    def points(self) -> np.ndarray:
        """Inner corners (N, 3), mm, row-major."""
        n = (self.rows - 1) * (self.cols - 1)
        i, j = np.divmod(np.arange(n), self.cols - 1)
        return np.stack([(j + 1 - self.cols / 2) * self.square, (i + 1 - self.rows / 2) * self.square,
                         np.zeros(n)], axis=1)

    true_points = points

    def draw(self) -> np.ndarray:
        """Reference image with exact area coverage of the (axis-aligned) squares."""
        H, W = _ref_shape(self)
        s = self.px_per_mm
        # coverage of pixel column u by square column j: overlap of [u − ½, u + ½] and the square
        xs = ((W - 1) / 2 + (np.arange(self.cols + 1) - self.cols / 2) * self.square * s)
        ys = ((H - 1) / 2 + (np.arange(self.rows + 1) - self.rows / 2) * self.square * s)
        cu = _overlaps(np.arange(W), xs)          # (W, cols)
        cv = _overlaps(np.arange(H), ys)          # (H, rows)
        dark = (np.add.outer(np.arange(self.rows), np.arange(self.cols)) % 2 == 0).astype(float)
        cover = cv @ dark @ cu.T
        return (self.light_grey + (self.dark_grey - self.light_grey) * cover).astype(np.float32)


@dataclass(frozen=True)
class Charuco:
    """OpenCV's ChArUco board (``cv2.aruco.CharucoBoard(...).generateImage``): squares_x ×
    squares_y squares of ``square`` mm with ArUco markers of ``marker`` mm from
    ``dictionary``; its points are the inner chessboard corners in OpenCV's id order."""
    squares_x: int = 7
    squares_y: int = 5
    square: float = 10.0
    marker: float = 7.0
    dictionary: str = "DICT_5X5_100"
    margin: float = 10.0
    px_per_mm: float = 10.0

    def __post_init__(self):
        import cv2
        check(hasattr(cv2.aruco, self.dictionary), "target.dictionary", f"{self.dictionary!r} is unknown",
              "use an OpenCV name such as DICT_5X5_100")
        check(0 < self.marker < self.square, "target.marker", f"must lie in (0, square), got {self.marker}",
              "the marker sits inside a square")
        px = self.square * self.px_per_mm
        check(abs(px - round(px)) < 1e-9, "target.px_per_mm",
              f"square × px_per_mm = {px:g} is not a whole number of pixels",
              "choose px_per_mm so that every square is a whole number of reference pixels")

    @property
    def size(self) -> tuple[float, float]:
        return (self.squares_x * self.square + 2 * self.margin, self.squares_y * self.square + 2 * self.margin)

    def board(self):
        import cv2
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, d)

    def points(self) -> np.ndarray:
        """Inner corners (N, 3) in the target frame, mm, in OpenCV's charuco id order."""
        p = np.asarray(self.board().getChessboardCorners(), np.float64)
        return p - [self.squares_x * self.square / 2, self.squares_y * self.square / 2, 0.0]

    true_points = points

    def draw(self) -> np.ndarray:
        """OpenCV's board image (binary, square-aligned pixels) inside a white margin."""
        H, W = _ref_shape(self)
        sq = int(round(self.square * self.px_per_mm))
        bw, bh = self.squares_x * sq, self.squares_y * sq
        board = self.board().generateImage((bw, bh), marginSize=0, borderBits=1)
        image = np.ones((H, W), np.float32)
        v0, u0 = (H - bh) // 2, (W - bw) // 2
        check((H - bh) % 2 == 0 and (W - bw) % 2 == 0, "target.margin",
              "the board does not sit on whole reference pixels", "use a margin of whole pixels")
        image[v0:v0 + bh, u0:u0 + bw] = board / 255.0
        return image


Target = DotGrid | Chessboard | Charuco


def _default_markers(rows: int, cols: int) -> tuple[tuple[int, int], ...]:
    r, c = rows // 2 - 1, cols // 2 - 1
    return ((r, c), (r, c + 1), (r + 2, c))


def symmetries(rows: int, cols: int, markers=()) -> list[np.ndarray]:
    """The in-plane turns of a rows × cols grid that keep it a rows × cols grid and map the
    marker cells onto themselves, each as a permutation p of point indices (point k of the
    turned grid is point p[k] of the original). The identity comes first."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    turns = [idx, np.rot90(idx, 2)] + ([np.rot90(idx, 1), np.rot90(idx, 3)] if rows == cols else [])
    cells = {r * cols + c for r, c in markers}
    return [t.ravel() for t in turns if {int(t.ravel()[k]) for k in cells} == cells]


def _ref_shape(target) -> tuple[int, int]:
    """(H, W) of the reference image: the plate plus PAD_PX, with the plate centred.

    W − 1 − (plate width in px) is even so that the centre falls on the same place for any
    whole-pixel layout (Charuco needs the board on pixel boundaries)."""
    w, h = target.size
    s = target.px_per_mm
    W = int(math.ceil(w * s - 1e-9)) + 2 * PAD_PX
    H = int(math.ceil(h * s - 1e-9)) + 2 * PAD_PX
    return H, W


def _overlaps(pixels: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Length of [p − ½, p + ½] ∩ [edges[k], edges[k + 1]] for each pixel p and interval k."""
    lo = np.maximum(pixels[:, None] - 0.5, edges[None, :-1])
    hi = np.minimum(pixels[:, None] + 0.5, edges[None, 1:])
    return np.clip(hi - lo, 0.0, None)


def _circle_integral(x, r):
    """∫₀ˣ √(r² − t²) dt for |x| ≤ r."""
    return 0.5 * (x * np.sqrt(np.maximum(r * r - x * x, 0.0)) + r * r * np.arcsin(np.clip(x / r, -1, 1)))


def _corner_area(x, y, r):
    """Signed area of the disc (centre 0, radius r) ∩ the rectangle spanned by (0, 0), (x, y)."""
    sign = np.sign(x) * np.sign(y)
    x, y = np.minimum(np.abs(x), r), np.minimum(np.abs(y), r)
    xs = np.minimum(np.sqrt(np.maximum(r * r - y * y, 0.0)), x)   # where the circle reaches height y
    area = np.where(x * x + y * y <= r * r, x * y,
                    xs * y + _circle_integral(x, r) - _circle_integral(xs, r))
    return sign * area


def disc_coverage(u, v, r):
    """Exact area of each unit pixel square centred at (u, v) covered by the disc of radius r
    (px) centred at the origin (clipped to [0, 1] against rounding, ~1e-14)."""
    a = lambda du, dv: _corner_area(u + du, v + dv, r)  # noqa: E731
    return np.clip(a(0.5, 0.5) - a(-0.5, 0.5) - a(0.5, -0.5) + a(-0.5, -0.5), 0.0, 1.0)


def reference(target) -> Reference:
    """The target's reference image and the pinhole that maps the plate in its canonical
    position (:func:`plate_mesh`) onto it: at the world origin, looking along +z, with
    f = REF_DISTANCE·px_per_mm so that a target point (x, y) lands on ((W−1)/2 + x·px_per_mm,
    (H−1)/2 + y·px_per_mm)."""
    image = target.draw()
    H, W = image.shape
    f = REF_DISTANCE * target.px_per_mm
    cam = Camera(name="reference", size=(W, H), fx=f, fy=f, cx=(W - 1) / 2, cy=(H - 1) / 2)
    return Reference(image, cam)


def plate_mesh(target, poses=()) -> meshmod.Mesh:
    """The target plate as a flat 2 × 2-element mesh in its canonical position (the target
    frame shifted by REF_DISTANCE along z, in the world frame) with one load step per pose.

    ``poses``: (R, t) pairs mapping the target frame to the world (mm). A rigid motion of a
    flat bilinear element is exactly bilinear, so the steps carry no discretisation error.
    """
    w, h = target.size
    m = meshmod.plate(w, h, 2, 2, center=(0.0, 0.0, REF_DISTANCE))
    local = m.nodes - [0.0, 0.0, REF_DISTANCE]
    steps = [local @ np.asarray(R, float).T + np.asarray(t, float) - m.nodes for R, t in poses]
    return meshmod.with_displacements(m, steps)
