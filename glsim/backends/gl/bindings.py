"""Every shader storage buffer, image and texture binding of the renderer's programs, in one
table: the shaders read them as ``#define BINDING_<NAME> n``, ``IMAGE_<NAME> n`` and
``SAMPLER_<NAME> n`` (prepended by glsim.backends.gl.programs; a sampler is declared
``layout(binding = SAMPLER_SRC) uniform sampler2D u_src;``), the Python side binds by name
(:func:`storage`, :func:`image`, :func:`sampler`). A sampler's unit is fixed in the program, so
no frame sets it. Numbers stay below 24 (GL 4.3 guarantees 8 storage bindings; Mesa has 80,
NVIDIA 96); texture units below 16, GL 4.5's least number per shader stage; image units
below 8, its least number per compute shader."""
from __future__ import annotations

STORAGE = {
    "ELEMENTS": 0,      # per-view element records (view.comp → pass 2: sample_map.glsl)
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
    "SHAPE": 11,        # the step's shape filter (shape.comp)
    "TIGHT": 12,        # per element: tight rectangles (candidate lists)
    "LIST_FLAGS": 13,   # candidate lists: several candidates / overflow / big covers
    "REF_LOCAL": 14,    # float32 exact, pinhole reference: per-element reference-frame records
    "PATCH_REF": 15,    # quadratic patches: reference data
    "LOCAL": 16,        # float32 exact: per-element camera-frame records (CAMERA_LOCAL)
    "REF_PINHOLE": 17,  # float64 exact, pinhole reference: per-element blends
    "PATCH_NODES": 18,  # quadratic patches: the step's control points
    "PIXEL_LISTS": 19,  # the compute pixel stage's pixels by layer (classify.comp → single.comp, resolve.comp)
    "FAST_TRIANGLES": 20,  # the compute pixel stage's fast triangles (fast_records.geom → fast_shade.comp)
}
IMAGES = {"CAND_COUNT": 0, "CAND_LIST": 1,   # candidate lists (candidates.glsl)
          # the deformation target written by the compute pixel stage (single.comp, resolve.comp, fast_shade.comp)
          "GREY": 2, "MAP": 3, "EXTRA": 4, "LO": 5, "DEPTH": 6,
          "PASS_OUT": 7,   # a full-screen pass's output in the compute stage (comp_pass.glsl)
          "PASS_OUT_B": 6}  # its second (blur.frag's row moments): DEPTH's unit, never bound in the same pass
SAMPLERS = {           # by the sampler's uniform name (SAMPLER_<name without u_, upper case>)
    "u_ref": 0,        # the reference speckle image (interp.glsl)
    "u_rays": 1,       # the ray map at the pass's samples (rays.frag)
    "u_count_tex": 2,  # candidate counts (candidates.glsl, pass 2)
    "u_list_tex": 3,   # candidate lists (candidates.glsl, pass 2)
    "u_centre_rays": 4,  # the ray map at pixel centres (subsamples.frag)
    "u_src": 5,        # an image pass's input grey
    "u_gain": 6,       # vignetting gain
    "u_depth": 7,      # depth per pixel (blur)
    "u_image": 8,      # the unblurred grey (blur)
    "u_moments": 9,    # blur moments
    "u_rows": 10,      # blur rows' records
    "u_variance": 11,  # noise variance table
    "u_samples": 12,   # the s×s samples (box filter)
    "u_kernel": 13,    # a PSF kernel
    "u_visibility": 14,  # each sample's fast triangle (the compute pixel stage)
}


def storage(name: str) -> int:
    return STORAGE[name]


def image(name: str) -> int:
    return IMAGES[name]


def sampler(name: str) -> int:
    """The texture unit of sampler uniform ``name``."""
    return SAMPLERS[name]


def sampler_define(name: str) -> str:
    """The macro the shaders declare sampler uniform ``name``'s binding with (u_src → SAMPLER_SRC)."""
    return f"SAMPLER_{name[2:].upper()}"


def defines() -> str:
    """The table as #define lines for the shaders."""
    return "\n".join([f"#define BINDING_{k} {v}" for k, v in STORAGE.items()] +
                     [f"#define IMAGE_{k} {v}" for k, v in IMAGES.items()] +
                     [f"#define {sampler_define(k)} {v}" for k, v in SAMPLERS.items()])
