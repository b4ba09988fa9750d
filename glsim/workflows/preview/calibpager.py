"""``glsim preview LIBRARY_DIR``: page through a calibration library (``glsim calib library``).

Each page is one stereo pair: the cameras' images side by side as recorded, the points
``glsim calib run`` detects drawn over them (green circles, joined in the target's row order
so that a grid detected turned or mirrored shows at once; the first point ringed in yellow),
the true position of every point it missed (red cross), and per camera how many points were
found, their mean and max distance from the truth (the true centroid for dots, else the
projected point), or why the view was skipped. Keys: Right / Left / Page Down / Page Up /
Space (next, previous), Home / End, q or Escape (quit). Detection runs on the page shown
(cached in memory), with the detector and ``min_points`` of ``glsim calib run``; nothing is
written into the library. No GL: the window shows the frame through the same presenter as
the scene preview, and ``--screenshot`` needs no display.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from glsim.errors import SceneError
from glsim.workflows.calib import calibrate as cal
from glsim.workflows.calib import library as libmod
from glsim.workflows.calib.detect import default_method
from glsim.workflows.preview import draw

GREEN, RED, YELLOW = (70, 230, 90), (255, 60, 60), (255, 230, 60)
INFO_H = 64           # px of text under the images
KEYS_NEXT = ("ArrowRight", "PageDown", " ", "n")
KEYS_PREV = ("ArrowLeft", "PageUp", "Backspace", "p")


def is_library(path: str | Path) -> bool:
    """Whether ``path`` is a calibration library folder (it holds library.json)."""
    return Path(path).is_dir() and (Path(path) / "library.json").is_file()


def display_grey(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """A recorded image (integers of ``bit_depth`` bits) as 8-bit display grey."""
    top = (1 << bit_depth) - 1
    return np.rint(np.clip(np.asarray(image, np.float64), 0, top) * (255.0 / top)).astype(np.uint8)


def fit_box(shape: tuple[int, int], box: tuple[int, int, int, int]) -> tuple[int, int, int, int, float]:
    """(x, y, w, h, scale) of an image of ``shape`` (H, W) fitted into ``box``, centred."""
    bx, by, bw, bh = box
    H, W = shape
    s = min(bw / W, bh / H)
    w, h = max(1, int(W * s)), max(1, int(H * s))
    return bx + (bw - w) // 2, by + (bh - h) // 2, w, h, s


def to_frame(uv: np.ndarray, x: int, y: int, s: float) -> np.ndarray:
    """Image pixel coordinates (centres at integers) → frame pixel coordinates of a tile
    placed at (x, y) with scale ``s`` (the tile's pixel centres at (k + 0.5) s − 0.5)."""
    return np.asarray(uv, np.float64) * s + 0.5 * s - 0.5 + [x, y]


class LibraryPager:
    """The pages of a calibration library; the same event and frame interface as
    :class:`glsim.workflows.preview.core.Preview`, so the window and ``--screenshot`` drive it."""

    def __init__(self, directory: str | Path, size=(1280, 800), min_points: int | None = None,
                 method: str | None = None):
        self.lib = libmod.load_library(directory)     # a broken library: its named SceneError
        if not self.lib.pairs:
            raise SceneError(str(Path(directory) / "pairs"), "holds no finished pair",
                             "make the library first: glsim calib library … -o DIR")
        cal.supported(self.lib)
        self.min_points = min_points or cal.default_min_points(self.lib.target)
        self.method = method or default_method(self.lib.target)
        self.size = (max(320, int(size[0])), max(240, int(size[1])))
        self.page = 0
        self.quit_requested = False
        self.show_timings = False      # (the scene preview's option; a page has no timings)
        self._cache: dict[int, tuple] = {}
        self._dirty = True
        self._frame: np.ndarray | None = None

    # ---- the window's interface --------------------------------------------------------------
    @property
    def needs_redraw(self) -> bool:
        return self._dirty

    @property
    def busy(self) -> bool:
        """A page is drawn once, in full: busy only until the changed page is drawn."""
        return self._dirty

    settle_seconds = 0.05

    def tick(self, now: float | None = None) -> bool:
        return self.needs_redraw

    def log_state(self) -> str:
        """One line per drawn frame (the window's --log-frames, tests)."""
        pair = self.lib.pairs[self.page]
        found = " ".join(f"{c.name}={n}" for c, n in zip(self.lib.cameras, self._found(self.page)))
        return f"frame page={self.page} pair={pair['pair']} quality=full found {found}"

    def close(self) -> None:
        self._cache.clear()

    def __enter__(self) -> "LibraryPager":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def resize(self, width: int, height: int) -> None:
        size = (max(320, int(width)), max(240, int(height)))
        if size != self.size:
            self.size, self._dirty = size, True

    def go(self, page: int) -> None:
        """Show page ``page`` (wrapping round the library)."""
        page %= len(self.lib.pairs)
        if page != self.page:
            self.page, self._dirty = page, True

    def handle_event(self, event: dict) -> bool:
        """jupyter_rfb-style events: keys page, a resize relayouts; True when the frame changed."""
        kind = event.get("type")
        if kind == "resize":
            self.resize(event["width"], event["height"])
        elif kind == "key_down":
            key = event.get("key", "")
            if key in KEYS_NEXT:
                self.go(self.page + 1)
            elif key in KEYS_PREV:
                self.go(self.page - 1)
            elif key == "Home":
                self.go(0)
            elif key == "End":
                self.go(len(self.lib.pairs) - 1)
            elif key in ("q", "Escape"):
                self.quit_requested = True
        return self._dirty

    # ---- detection and drawing ---------------------------------------------------------------
    def detection(self, page: int) -> tuple[list, list[str]]:
        """Per camera the detected points (N, 2) px or None, and why a view found nothing."""
        if page not in self._cache:
            pair = self.lib.pairs[page]
            cams = self.lib.cameras
            job = (pair["pair"], [str(self.lib.image_path(pair, c)) for c in cams], [c.bit_depth for c in cams],
                   [c.size for c in cams], libmod.target_to_dict(self.lib.target), self.min_points, self.method)
            _, points, why = cal._detect_job(job)
            if why is None:                                   # (file, problem, fix) of a bad image
                raise SceneError(*points)
            self._cache[page] = ([None if np.all(np.isnan(p)) else p for p in points], why)
        return self._cache[page]

    def _found(self, page: int) -> list[int]:
        points, _ = self.detection(page)
        return [0 if p is None else int(np.isfinite(p[:, 0]).sum()) for p in points]

    def errors(self, page: int) -> list[tuple[int, float, float] | None]:
        """Per camera (points found, mean, max |detected − true| px) against the true centroid
        (dots) or projected point (corners); None where the view found nothing."""
        points, _ = self.detection(page)
        pair = self.lib.pairs[page]
        out = []
        for cam, p in zip(self.lib.cameras, points):
            truth = libmod.image_truth(self.lib, pair, cam)
            ref = truth.get("centroid", truth["projected"])
            if p is None:
                out.append(None)
                continue
            ok = np.isfinite(p[:, 0]) & np.isfinite(ref[:, 0])
            d = np.linalg.norm(p[ok] - ref[ok], axis=1)
            out.append((int(ok.sum()), float(d.mean()) if d.size else float("nan"),
                        float(d.max()) if d.size else float("nan")))
        return out

    def layout(self) -> list[tuple[int, int, int, int]]:
        """The tiles' boxes (x, y, w, h) in the frame, one per camera, side by side."""
        W, H = self.size
        n = len(self.lib.cameras)
        w = (W - 8 * (n + 1)) // n
        return [(8 + k * (w + 8), 8, w, H - INFO_H - 16) for k in range(n)]

    def frame(self, quality: str | None = None) -> np.ndarray:
        """The page as an H×W×3 uint8 RGB frame."""
        W, H = self.size
        frame = np.full((H, W, 3), draw.BACKGROUND, np.uint8)
        pair = self.lib.pairs[self.page]
        points, why = self.detection(self.page)
        errs = self.errors(self.page)
        for k, (cam, box) in enumerate(zip(self.lib.cameras, self.layout())):
            image = cal._read_view(str(self.lib.image_path(pair, cam)), cam.bit_depth, cam.size)
            x, y, w, h, s = fit_box(image.shape, box)
            grey = cv2.resize(display_grey(image, cam.bit_depth), (w, h), interpolation=cv2.INTER_AREA)
            frame[y:y + h, x:x + w] = grey[..., None]
            self._draw_points(frame, points[k], libmod.image_truth(self.lib, pair, cam), x, y, s)
            line = f"{cam.name}: "
            if errs[k] is None:
                line += f"skipped — {why[k] or 'no points found'}"
            else:
                n, mean, mx = errs[k]
                line += (f"{n}/{len(self.lib.target.points())} points, |detected - true| mean {mean:.4f} px, "
                         f"max {mx:.4f} px")
            draw.text(frame, line, box[0], H - INFO_H + 14, draw.WHITE if errs[k] else RED)
        draw.text(frame, f"pair {pair['pair']} ({self.page + 1}/{len(self.lib.pairs)})  motion: {pair.get('kind', '?')}"
                  f"  detector: {self.method}, min {self.min_points} points  —  Left/Right: page, q: quit",
                  8, H - INFO_H + 38, draw.GREY)
        draw.text(frame, f"{self.lib.directory}", 8, H - INFO_H + 58, draw.DIM)
        self._frame, self._dirty = frame, False
        return frame

    @staticmethod
    def _draw_points(frame, points, truth, x, y, s) -> None:
        shift = 4                                          # cv2 sub-pixel drawing: 1/16 px
        P = lambda q: tuple(int(round(c * (1 << shift))) for c in q)   # noqa: E731
        true_uv = to_frame(truth["projected"], x, y, s)
        if points is None:
            found = np.zeros(len(true_uv), bool)
        else:
            found = np.isfinite(points[:, 0])
            uv = to_frame(points, x, y, s)
            run = [q for q in uv[found]]
            for a, b in zip(run[:-1], run[1:]):
                cv2.line(frame, P(a), P(b), (40, 120, 50), 1, cv2.LINE_AA, shift)
            for q in uv[found]:
                cv2.circle(frame, P(q), 4 << shift, GREEN, 1, cv2.LINE_AA, shift)
            if found.any():
                cv2.circle(frame, P(uv[np.flatnonzero(found)[0]]), 8 << shift, YELLOW, 2, cv2.LINE_AA, shift)
        visible = truth.get("visible", np.ones(len(true_uv), bool))
        for q in true_uv[~found & visible]:
            a, b = P(q - 4), P(q + 4)
            cv2.line(frame, a, b, RED, 1, cv2.LINE_AA, shift)
            cv2.line(frame, (a[0], b[1]), (b[0], a[1]), RED, 1, cv2.LINE_AA, shift)

    def screenshot(self, path: str | Path) -> Path:
        """The page as PNG (temporary name, then rename)."""
        return draw.save_png(path, self.frame)
