"""The design tests' scenes and spec files: a camera square onto a flat plate, and a spec around it."""
from __future__ import annotations

from pathlib import Path


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
