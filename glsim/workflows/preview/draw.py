"""Drawing the preview's frame with OpenCV on RGB uint8 arrays: text, the 3-D rig view
(specimen, camera frusta, lights), colour bars. No GL."""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from glsim.errors import SceneError
from glsim.scene.camera import Camera, look_at

FONT = cv2.FONT_HERSHEY_SIMPLEX
WHITE, GREY, DIM = (235, 235, 235), (150, 150, 150), (90, 90, 90)
CAMERA_COLOURS = ((80, 170, 255), (255, 150, 60), (120, 220, 120), (230, 90, 200))
LIGHT_COLOUR = (255, 230, 80)
BACKGROUND = (28, 28, 32)


def text(img: np.ndarray, s: str, x: int, y: int, colour=WHITE, scale: float = 0.42) -> int:
    """Draw ``s`` with its baseline at ``y``; returns the x after it."""
    cv2.putText(img, s, (int(x), int(y)), FONT, scale, colour, 1, cv2.LINE_AA)
    return int(x) + cv2.getTextSize(s, FONT, scale, 1)[0][0]


def text_width(s: str, scale: float = 0.42) -> int:
    return cv2.getTextSize(s, FONT, scale, 1)[0][0]


@dataclass
class Orbit:
    """The rig view's own virtual camera: it orbits ``target`` at ``azimuth``/``elevation``
    (deg) about the rig's ``up`` axis, ``distance`` mm away, shifted by ``pan`` (mm, in its
    image plane)."""
    target: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    distance: float
    azimuth: float = -35.0
    elevation: float = 25.0
    pan: tuple = (0.0, 0.0)
    fov: float = 40.0

    def pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R, t, eye): world→view."""
        key = (self.azimuth, self.elevation, tuple(self.pan), self.distance)
        if getattr(self, "_pose_key", None) == key:
            return self._pose
        self._pose_key, self._pose = key, self._compute_pose()
        return self._pose

    def _compute_pose(self):
        up = self.up / np.linalg.norm(self.up)
        f = self.forward - (self.forward @ up) * up
        f = f / np.linalg.norm(f)
        side = np.cross(up, f)
        a, e = math.radians(self.azimuth), math.radians(self.elevation)
        d = math.cos(e) * (math.cos(a) * f + math.sin(a) * side) + math.sin(e) * up
        R, _ = look_at(self.target + self.distance * d, self.target, up)
        centre = self.target + R[0] * self.pan[0] + R[1] * self.pan[1]
        eye = centre + self.distance * d
        R, t = look_at(eye, centre, up)
        return R, t, eye

    def project(self, X: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) → view pixels (..., 2) and their depths (...)."""
        R, t, _ = self.pose()
        W, H = size
        Xc = np.asarray(X, float) @ R.T + t
        f = 0.5 * H / math.tan(math.radians(self.fov) / 2)
        z = Xc[..., 2]
        zs = np.where(z > 1e-6, z, 1e-6)
        uv = np.stack([f * Xc[..., 0] / zs + W / 2, f * Xc[..., 1] / zs + H / 2], axis=-1)
        return uv, z


def _segments(orbit: Orbit, size, a: np.ndarray, b: np.ndarray, near: float = 1.0) -> list[np.ndarray]:
    """Segments a→b (N, 3) clipped at the view's near plane, as pixel polylines."""
    R, t, _ = orbit.pose()
    za, zb = a @ R[2] + t[2], b @ R[2] + t[2]
    keep = (za > near) | (zb > near)
    a, b, za, zb = a[keep], b[keep], za[keep], zb[keep]
    s = np.clip((near - za) / np.where(zb != za, zb - za, 1), 0, 1)[:, None]
    a2 = np.where((za < near)[:, None], a + s * (b - a), a)
    s2 = np.clip((near - zb) / np.where(za != zb, za - zb, 1), 0, 1)[:, None]
    b2 = np.where((zb < near)[:, None], b + s2 * (a - b), b)
    uv, _ = orbit.project(np.stack([a2, b2], axis=1), size)
    return [np.rint(p * 16).astype(np.int32) for p in uv]


def _lines(img, orbit, a, b, colour, thickness=1):
    segs = _segments(orbit, img.shape[1::-1], np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3))
    if segs:
        cv2.polylines(img, segs, False, colour, thickness, cv2.LINE_AA, shift=4)


def frustum(cam: Camera, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre and the four image corners' points at ``depth`` mm (world), pinhole."""
    W, H = cam.size
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    x = (corners[:, 0] - cam.cx - cam.skew * (corners[:, 1] - cam.cy) / cam.fy) / cam.fx
    y = (corners[:, 1] - cam.cy) / cam.fy
    P = np.stack([x * depth, y * depth, np.full(4, depth)], axis=1)
    return cam.center, (P - cam.translation) @ cam.rotation


def rig_view(size: tuple[int, int], orbit: Orbit, cameras, active: int, deformed: np.ndarray,
             quads: np.ndarray, lights=(), labels: bool = True, target=None) -> np.ndarray:
    """The 3-D set-up: mesh edges (outline brighter), each camera's frustum to the target and
    its optical axis, lights (spotlights with their cone), world axes at the target."""
    W, H = size
    img = np.full((H, W, 3), BACKGROUND, np.uint8)
    edges = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    edges = np.sort(edges[edges[:, 0] != edges[:, 1]], axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    inner, outline = uniq[count > 1], uniq[count == 1]
    _lines(img, orbit, deformed[inner[:, 0]], deformed[inner[:, 1]], (110, 110, 120))
    _lines(img, orbit, deformed[outline[:, 0]], deformed[outline[:, 1]], WHITE, 2)
    T = orbit.target if target is None else np.asarray(target, float)
    L = 0.1 * orbit.distance
    for k, colour in enumerate(((220, 70, 70), (70, 200, 70), (70, 110, 230))):
        e = np.zeros(3)
        e[k] = L
        _lines(img, orbit, T, T + e, colour)
    for i, cam in enumerate(cameras):
        colour = CAMERA_COLOURS[i % len(CAMERA_COLOURS)]
        if i != active:
            colour = tuple(int(0.6 * c) for c in colour)
        depth = float(np.linalg.norm(cam.center - T) * 1.0)
        C, P = frustum(cam, depth * 0.35)
        _lines(img, orbit, np.repeat(C[None], 4, 0), P, colour, 2 if i == active else 1)
        _lines(img, orbit, P, np.roll(P, -1, axis=0), colour, 2 if i == active else 1)
        _lines(img, orbit, C, C + cam.rotation[2] * depth, tuple(int(c * 0.7) for c in colour))
        if labels:
            uv, z = orbit.project(C, size)
            if z > 0:
                text(img, cam.name, uv[0] + 6, uv[1] - 6, colour)
    for j, light in enumerate(lights):
        p = np.asarray(light.position, float)
        uv, z = orbit.project(p, size)
        if z > 0:
            cv2.circle(img, (int(uv[0]), int(uv[1])), 5, LIGHT_COLOUR, -1, cv2.LINE_AA)
            if labels:
                text(img, f"light {j}", uv[0] + 7, uv[1] + 4, LIGHT_COLOUR)
        if light.direction is not None:
            d = np.asarray(light.direction, float)
            d /= np.linalg.norm(d)
            reach = float(np.linalg.norm(T - p))
            _lines(img, orbit, p, p + d * reach, LIGHT_COLOUR)
            if light.cutoff < 90:
                a = np.cross(d, orbit.up)
                a = a / np.linalg.norm(a) if np.linalg.norm(a) > 1e-9 else np.array([1.0, 0, 0])
                b = np.cross(d, a)
                r = reach * math.tan(math.radians(light.cutoff))
                ring = [p + d * reach + r * (math.cos(s) * a + math.sin(s) * b) for s in np.linspace(0, 2 * math.pi, 25)]
                ring = np.array(ring)
                _lines(img, orbit, ring[:-1], ring[1:], tuple(int(c * 0.7) for c in LIGHT_COLOUR))
                _lines(img, orbit, np.repeat(p[None], 4, 0), ring[[0, 6, 12, 18]], tuple(int(c * 0.5) for c in LIGHT_COLOUR))
    if labels:
        text(img, "rig view: drag to orbit, shift/right-drag to pan, wheel to zoom", 6, H - 8, GREY, 0.38)
    return img


def colour_bar(img: np.ndarray, x: int, y: int, w: int, h: int, lo: float, hi: float, ticks, label: str,
               second=None) -> None:
    """A horizontal viridis bar at (x, y) of w×h with tick labels below; ``second``: (scale,
    unit) for a second row of labels (value·scale)."""
    ramp = np.linspace(0, 255, w).astype(np.uint8)[None].repeat(h, 0)
    bar = cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[..., ::-1]
    img[y:y + h, x:x + w] = bar
    cv2.rectangle(img, (x - 1, y - 1), (x + w, y + h), GREY, 1)
    text(img, label, x, y - 5, WHITE, 0.4)
    span = hi - lo if hi > lo else 1.0
    for t in ticks:
        px = int(round(x + (t - lo) / span * (w - 1)))
        cv2.line(img, (px, y + h), (px, y + h + 4), WHITE, 1)
        s = f"{t:.3g}"
        text(img, s, px - text_width(s, 0.36) // 2, y + h + 16, WHITE, 0.36)
        if second is not None:
            s2 = f"{t * second[0]:.3g}"
            text(img, s2, px - text_width(s2, 0.36) // 2, y + h + 30, GREY, 0.36)
    if second is not None:
        text(img, second[1], x + w + 6, y + h + 30, GREY, 0.36)


def save_png(path, make_frame):
    """Write the RGB frame ``make_frame()`` gives to ``path`` as PNG (temporary name, then
    rename); a path not ending in .png is refused before any frame is made."""
    from pathlib import Path

    import imageio.v3 as iio
    from glsim.io.images import atomic_path

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise SceneError(str(path), "a screenshot is saved as PNG", "give a file name ending in .png")
    frame = make_frame()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, frame, extension=".png")
    return path
