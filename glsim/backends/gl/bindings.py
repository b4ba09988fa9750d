"""Every shader storage buffer and image binding of the renderer's programs, in one table: the
shaders read them as ``#define BINDING_<NAME> n`` (prepended by glsim.backends.gl.programs), the
Python side binds by name (:func:`storage`, :func:`image`). Numbers stay below 24 (GL 4.3
guarantees 8 storage bindings; Mesa has 80, NVIDIA 96)."""
from __future__ import annotations

STORAGE = {
    "ELEMENTS": 0,      # per-view element records (view.comp → deform.frag)
    "NORMALS": 1,       # the step's corner normals (lighting)
    "DOTS": 2,          # procedural speckle: dots
    "DOT_CELLS": 3,     # procedural speckle: its grid cells
    "DROPPED": 4,       # samples mapping outside the reference (a counter)
    "QUADS": 5,         # connectivity
    "NODES": 6,         # the step's nodes, local frame
    "REF_UV": 7,        # per node: reference-image px (q4, fast)
    "REF_XR": 8,        # per node: undeformed, reference camera frame (exact)
    "COVER": 9,         # per element: cover rectangle corners
    "FLAGS": 10,        # element problems (bitsets)
    "EXCLUDED": 11,     # elements left out (bitset)
    "TIGHT": 12,        # per element: tight rectangles (candidate lists)
    "LIST_FLAGS": 13,   # candidate lists: several candidates / overflow / big covers
    "REF_LOCAL": 14,    # float32 exact, pinhole reference: per-element reference-frame records
    "PATCH_REF": 15,    # quadratic patches: reference data
    "LOCAL": 16,        # float32 exact: per-element camera-frame records (CAMERA_LOCAL)
    "REF_PINHOLE": 17,  # float64 exact, pinhole reference: per-element blends
    "PATCH_NODES": 18,  # quadratic patches: the step's control points
}
IMAGES = {"CAND_COUNT": 0, "CAND_LIST": 1}


def storage(name: str) -> int:
    return STORAGE[name]


def image(name: str) -> int:
    return IMAGES[name]


def defines() -> str:
    """The table as #define lines for the shaders."""
    return "\n".join([f"#define BINDING_{k} {v}" for k, v in STORAGE.items()] +
                     [f"#define IMAGE_{k} {v}" for k, v in IMAGES.items()])
