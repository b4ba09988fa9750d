"""The design tests' scenes and spec files: a camera square onto a flat plate, a stereo rig on a
plate, a spec around them, and a stand-in stereo engine that answers the truth plus known errors."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import tifffile

from glsim.io.fe import specimen_mesh
from glsim.io.truth import mesh_geometry
from glsim.scene.locate import points_truth
from glsim.workflows.design import quick
from glsim.workflows.design.engine import StereoResults


def s_curve_gain() -> float:
    """The largest relative bias |bias_u/shift| of pyvale's 2-D match on exactly shifted noise-free
    model images (bench/results/sweep.json, subset 21; docs/verify.md): near zero shift the S-curve
    is a gain error — a small motion is measured short by up to this share."""
    sweep = json.loads((Path(__file__).resolve().parents[1] / "bench" / "results" / "sweep.json").read_text())
    model = next(r for r in sweep["results"] if r["sequence"] == "model" and r["subset_size"] == 21)
    return max(abs(r["bias_u"] / r["shift_px"]) for r in model["rows"] if 0 < r["shift_px"] <= 0.5)


def plate_scene(size=(200, 160), shift_px=(2.0, 0.0), sigma=2.0, bit_depth=16) -> dict:
    """A camera square onto a flat plate at 300 mm, 0.1 mm per px, moved by an image shift at step 1."""
    W, H = size
    return {"cameras": [{"name": "cam0", "size": [W, H], "fx": 3000.0, "fy": 3000.0, "cx": (W - 1) / 2,
                         "cy": (H - 1) / 2, "bit_depth": bit_depth}],
            "specimen": {"plate": {"width": 0.1 * (W - 20), "height": 0.1 * (H - 20), "nx": 2, "ny": 2,
                                   "translations": [[0.1 * shift_px[0], 0.1 * shift_px[1], 0.0]]},
                         "pose": {"t": [0.0, 0.0, 300.0]}},
            "speckle": {"dot_diameter_px": 5.0, "seed": 3}, "noise": {"sigma": sigma},
            "render": {"backend": "cpu", "mode": "exact"}}


def write_spec(path: Path, scene: dict, **top) -> Path:
    """A design spec file: ``top`` keys (tables as dicts) and the inline base scene."""
    import tomli_w
    path.write_bytes(tomli_w.dumps({**top, "scene": scene}).encode())
    return path


def stereo_plate(size=(256, 256), angle=20.0, shift_mm=(0.15, -0.1, 0.4), sigma=None, bit_depth=16,
                 dist=300.0, aside_mm=0.0) -> dict:
    """A flat plate 300 mm in front of camera 0 (0.1 mm per px), turned by half the stereo angle so
    that it faces the rig's bisector; camera 1 aimed at the plate's centre (Phi = angle, Tx =
    −dist·sin, Tz = dist·(1 − cos)), moved ``aside_mm`` further along its x; the plate translated
    rigidly by ``shift_mm`` (plate axes) at step 1."""
    W, H = size
    a = math.radians(angle)

    def cam(name):
        return {"name": name, "size": [W, H], "fx": 3000.0, "fy": 3000.0, "cx": (W - 1) / 2, "cy": (H - 1) / 2,
                "bit_depth": bit_depth}
    c1 = cam("cam1")
    c1["pose"] = {"stereo": {"Tx": -dist * math.sin(a) - aside_mm, "Ty": 0.0, "Tz": dist * (1 - math.cos(a)),
                             "Theta": 0.0, "Phi": angle, "Psi": 0.0}}
    scene = {"cameras": [cam("cam0"), c1],
             "specimen": {"plate": {"width": 0.1 * (W - 40), "height": 0.1 * (H - 40), "nx": 2, "ny": 2,
                                    "translations": [list(shift_mm)]},
                          "pose": {"rvec": [0.0, -a / 2, 0.0], "t": [0.0, 0.0, dist]}},
             "speckle": {"dot_diameter_px": 5.0, "seed": 3}, "render": {"backend": "cpu", "mode": "exact"}}
    if sigma:
        scene["noise"] = {"sigma": sigma}
    return scene


def plate_rotation(angle=20.0) -> np.ndarray:
    """The plate's pose: a turn of −angle/2 about y, written out (not glsim's Rodrigues)."""
    h = -math.radians(angle) / 2
    return np.array([[math.cos(h), 0, math.sin(h)], [0, 1, 0], [-math.sin(h), 0, math.cos(h)]])


def pinhole(cam, X_cam0: np.ndarray) -> np.ndarray:
    """Camera-0-frame points (camera 0 is the world here) → pixels of ``cam``, written out."""
    Xc = X_cam0 @ np.asarray(cam.rotation).T + np.asarray(cam.translation)
    return np.stack([cam.fx * Xc[:, 0] / Xc[:, 2] + cam.cx, cam.fy * Xc[:, 1] / Xc[:, 2] + cam.cy], axis=1)


# ---- a stand-in engine: the maps against injected errors ----------------------------------------------
BIAS = {"X": 0.002, "Y": -0.001, "Z": 0.005, "U": 0.003, "V": -0.002, "W": 0.01}
SPREAD = 0.004                # realisation r adds (−1, 0, +1)[r] × SPREAD to every measured value


@dataclasses.dataclass
class StandIn:
    """A stereo engine that reads the exchange folder as verify/dic.py does and answers the exact
    truth plus BIAS plus a per-realisation offset; every 7th subset invalid in the deformed state."""
    scene: object
    step: int
    name: str = "pyvale3d"
    calls: int = 0
    seen: list = dataclasses.field(default_factory=list)

    def missing(self):
        return None

    def measure(self, exchange: Path) -> StereoResults:
        manifest = json.loads((exchange / "manifest.json").read_text())
        self.seen.append((exchange, manifest))
        roi = tifffile.imread(exchange / manifest["roi"]) > 0
        kw = manifest["calculate_3d"]
        c = quick.grid_centres(roi, kw["subset_size"], kw["subset_step"]).astype(float)
        g = mesh_geometry(specimen_mesh(self.scene))
        t = points_truth(g, self.scene.camera("cam0"), c, self.step)
        off = (-1, 0, 1)[self.calls % 3] * SPREAD
        self.calls += 1
        n = len(c)
        X0 = t.X_undeformed + [BIAS["X"], BIAS["Y"], BIAS["Z"]]
        states = {"X": [], "U": []}
        for k, (Xk, Uk) in enumerate([(X0, np.zeros((n, 3))),
                                      (X0 + off, np.full((n, 3), off)),
                                      (None, t.displacement + [BIAS["U"], BIAS["V"], BIAS["W"]] + off)]):
            states["U"].append(Uk)
            states["X"].append(Xk if Xk is not None else X0 + Uk)
        X, U = np.stack(states["X"]), np.stack(states["U"])
        valid = np.ones((3, n), bool)
        valid[2, ::7] = False
        return StereoResults(c[:, 0], c[:, 1], X[..., 0], X[..., 1], X[..., 2], U[..., 0], U[..., 1], U[..., 2],
                             valid, np.ones((3, n)), 0.0, "stand-in")
