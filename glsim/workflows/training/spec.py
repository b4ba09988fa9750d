"""A library spec's ``[training]`` table: the spec makes a training set (shards of samples)
instead of variant folders. Each variant is one sample: its cameras at step 0 and at ``step``,
and the per-pixel labels between them (:func:`glsim.workflows.training.labels.pair_labels`).

    [training]
    format = "webdataset"      # tar shards (the only format)
    shard_bytes = 1_000_000_000  # target shard size: the samples per shard follow from the sample's size
    step = 1                   # the deformed state (step 0 is the reference)
    cameras = ["cam0"]         # one (2-D) or two (stereo, camera 0 first); names or indices (default: every camera)
    crop = [256, 256]          # optional: one fixed-size crop per sample, placed from the seed
    labels = ["flow", "mask_flow"]   # which labels to keep (default: all)
    image_dtype = "uint8"      # uint8 or uint16 (default: from the camera's bit depth)
    image_format = "png"       # png or npy

Every key is checked (by name, with the fix) and every variant expanded and checked before
anything is written. The number of samples per shard is fixed from the sample's size as the
spec gives it (image and label shapes and dtypes), never from a measurement: the same spec
always cuts the same shards.
"""
from __future__ import annotations

import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.limits import check_memory
from glsim.workflows.library.spec import LibraryPlan, SpecError, expand, read_spec

KEYS = ("format", "shard_bytes", "step", "cameras", "crop", "labels", "image_dtype", "image_format")
FORMATS = ("webdataset",)
IMAGE_DTYPES = ("uint8", "uint16")
IMAGE_FORMATS = ("png", "npy")
SHARD_BYTES = 1_000_000_000
MAX_SHARD_BYTES = 1 << 40
LIBRARY_ONLY = ("steps", "truth", "truth_dtype", "cameras")   # top-level keys [training] replaces

# label families → (channels, bytes per channel); per camera i the name gets i appended (flow0)
PER_CAMERA = {"flow": (2, 4), "forward": (2, 4), "mask_flow": (1, 1), "mask_forward": (1, 1)}
STEREO = {"disparity_ref": (2, 4), "disparity_def": (2, 4), "mask_disparity_ref": (1, 1),
          "mask_disparity_def": (1, 1)}
SHARED = {"uvw": (3, 4), "mask_uvw": (1, 1)}
MEMBER_OVERHEAD = 512 + 512 + 128   # a tar header, padding at most, an .npy header


@dataclass(frozen=True)
class Training:
    """The ``[training]`` table, checked."""
    format: str
    shard_bytes: int
    step: int
    cameras: tuple            # as given (names or indices), or () for every camera
    crop: tuple | None        # (w, h)
    labels: tuple             # label names as given (families or per-camera names), () for all
    image_dtype: str | None   # None: from each camera's bit depth
    image_format: str

    def as_dict(self) -> dict:
        return {"format": self.format, "shard_bytes": self.shard_bytes, "step": self.step,
                "cameras": list(self.cameras), "crop": list(self.crop) if self.crop else None,
                "labels": list(self.labels), "image_dtype": self.image_dtype, "image_format": self.image_format}


@dataclass(frozen=True)
class Shard:
    name: str                 # shard-000000.tar
    variants: tuple           # variant ids, contiguous


@dataclass(frozen=True)
class TrainingPlan:
    """A training spec expanded: the library plan (variants), the table, the cameras and the shards."""
    library: LibraryPlan
    training: Training
    cameras: tuple            # camera names (of the first variant; every variant has them)
    indices: tuple            # their indices in the scene (the i of cam{i} and flow{i})
    labels: tuple             # the per-camera label names kept, () for all
    sample_bytes: int
    per_shard: int
    shards: tuple

    def fingerprint(self) -> str:
        return self._fingerprint

    @functools.cached_property
    def _fingerprint(self) -> str:
        """(once: it hashes every variant's scene)"""
        h = hashlib.sha256(self.library.fingerprint().encode())
        h.update(json.dumps(self.training.as_dict(), sort_keys=True).encode())
        return h.hexdigest()

    def shard_of(self) -> dict:
        return {vid: s.name for s in self.shards for vid in s.variants}


def _fail(key: str, problem: str, fix: str):
    raise SpecError(f"training.{key}: {problem} — {fix}")


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_table(table) -> Training:
    """The ``[training]`` table checked key by key (SpecError naming ``training.KEY`` and the fix)."""
    if not isinstance(table, dict):
        raise SpecError(f"training: expected a table, got {table!r} — write [training] with format = \"webdataset\"")
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        import difflib
        close = difflib.get_close_matches(unknown[0], KEYS, 1)
        _fail(unknown[0], "unknown key", (f"did you mean {close[0]!r}? " if close else "") + f"[training] has "
              f"{', '.join(KEYS)}")
    fmt = table.get("format", "webdataset")
    if fmt not in FORMATS:
        _fail("format", f"{fmt!r} is not one of {FORMATS}", 'write format = "webdataset" (tar shards; zarr is not '
              "written by this version)")
    sb = table.get("shard_bytes", SHARD_BYTES)
    if not (_int(sb) and 1 <= sb <= MAX_SHARD_BYTES):
        _fail("shard_bytes", f"expected an integer of bytes from 1 to 2⁴⁰, got {sb!r}", "write shard_bytes = "
              "1_000_000_000 (1 GB, the default)")
    step = table.get("step", 1)
    if not (_int(step) and step >= 1):
        _fail("step", f"expected a load step ≥ 1, got {step!r}", "write step = 1 (step 0 is the reference state)")
    cams = table.get("cameras", [])
    if not (isinstance(cams, list) and all((_int(c) or isinstance(c, str)) for c in cams)):
        _fail("cameras", f"expected a list of camera names or indices, got {cams!r}", 'write cameras = ["cam0"]')
    if len(set(map(str, cams))) != len(cams):
        _fail("cameras", f"{cams} names a camera twice", "list each camera once")
    crop = table.get("crop")
    if crop is not None and not (isinstance(crop, list) and len(crop) == 2 and all(_int(c) and c >= 1 for c in crop)):
        _fail("crop", f"expected [width, height] in px (integers ≥ 1), got {crop!r}", "write crop = [256, 256], or "
              "leave it out for whole images")
    labels = table.get("labels", [])
    if not (isinstance(labels, list) and all(isinstance(x, str) for x in labels)):
        _fail("labels", f"expected a list of label names, got {labels!r}", 'write labels = ["flow", "mask_flow"]')
    dtype = table.get("image_dtype")
    if dtype is not None and dtype not in IMAGE_DTYPES:
        _fail("image_dtype", f"{dtype!r} is not one of {IMAGE_DTYPES}", "leave it out to follow the camera's bit "
              "depth (8 bits: uint8, 10–16 bits: uint16)")
    ifmt = table.get("image_format", "png")
    if ifmt not in IMAGE_FORMATS:
        _fail("image_format", f"{ifmt!r} is not one of {IMAGE_FORMATS}", 'write image_format = "png" (or "npy")')
    return Training(fmt, sb, step, tuple(cams), tuple(crop) if crop else None, tuple(labels), dtype, ifmt)


def label_names(names, indices, stereo: bool) -> tuple:
    """The label names kept: each given name checked; a family name (flow) stands for every
    camera's (flow0, flow1)."""
    per = [f"{k}{i}" for k in PER_CAMERA for i in indices]
    allowed = per + (list(STEREO) if stereo else []) + list(SHARED)
    out = []
    for name in names:
        if name in PER_CAMERA:
            out += [f"{name}{i}" for i in indices]
        elif name in allowed:
            out.append(name)
        elif name in STEREO:
            _fail("labels", f"{name!r} needs two cameras (a stereo pair), and {len(indices)} is selected",
                  "select two cameras in training.cameras, or drop it")
        else:
            _fail("labels", f"{name!r} is not a label", f"use one of {', '.join([*PER_CAMERA, *STEREO, *SHARED])}"
                  f" (a family name like flow keeps every camera's: {', '.join(per[:2])})")
    return tuple(dict.fromkeys(out))


def _label_bytes(name: str, pixels: int) -> int:
    base = name.rstrip("0123456789") if name.rstrip("0123456789") in PER_CAMERA else name
    ch, b = {**PER_CAMERA, **STEREO, **SHARED}[base]
    return ch * b * pixels


def sample_bytes(cams, t: Training, labels, indices, stereo: bool) -> int:
    """The size of one sample as the spec fixes it (images and labels raw, their member
    overheads, the JSON): what cuts the shards, never a measurement."""
    size = 4096
    for cam in cams:
        w, h = t.crop or cam.size
        item = 1 if (t.image_dtype or ("uint8" if cam.bit_depth == 8 else "uint16")) == "uint8" else 2
        size += 2 * (w * h * item + MEMBER_OVERHEAD)
    w, h = t.crop or cams[0].size
    names = labels or label_names([*PER_CAMERA, *(STEREO if stereo else {}), *SHARED], indices, stereo)
    return size + sum(_label_bytes(n, w * h) + MEMBER_OVERHEAD for n in names)


def expand_training(spec: dict, spec_dir: str | Path = ".", sample: int | None = None) -> TrainingPlan:
    """Expand and check a spec with ``[training]`` (SpecError naming the key, the variant and the fix)."""
    t = check_table(spec["training"])
    for key in LIBRARY_ONLY:
        if key in spec:
            fix = {"cameras": "give them in [training] as cameras = [...]", "steps": "give the deformed step in "
                   "[training] as step = 1 (step 0 is always the reference)"}.get(key, "remove it: a training set "
                                                                                    "holds labels, not truth files")
            raise SpecError(f"{key}: is a library key, not used with [training] — {fix}")
    lib = {k: v for k, v in spec.items() if k != "training"}
    lib.update(truth=False, steps=[0], **({"cameras": list(t.cameras)} if t.cameras else {}))
    try:
        plan = expand(lib, spec_dir, sample, keep_meshes=False)
    except SpecError as exc:
        raise SpecError(str(exc).replace(": cameras:", ": training.cameras:", 1)) from None
    first = plan.variants[0].scene
    names = plan.cameras
    indices = tuple(range(len(names)))      # cam{i}, flow{i}: the i-th camera selected (pair_labels' order)
    if len(names) > 2:
        raise SpecError(f"training.cameras: {len(names)} cameras ({', '.join(names)}) — select one (2-D) or two "
                        "(a stereo pair, camera 0 first): cameras = [\"cam0\", \"cam1\"]")
    for v in plan.variants:
        where = f"variant {v.id}" + (f" ({v.label()})" if v.params else "")
        nsteps = plan.n_steps[v.id]
        if t.step >= nsteps:
            raise SpecError(f"{where}: training.step: step {t.step} does not exist (the specimen has steps 0…"
                            f"{nsteps - 1}) — give a step from 1…{nsteps - 1}, or give the specimen a deformed state")
        cams = [v.scene.camera(n) for n in names]
        for c in cams:
            if t.crop and (t.crop[0] > c.width or t.crop[1] > c.height):
                raise SpecError(f"{where}: training.crop: {list(t.crop)} is larger than camera {c.name}'s "
                                f"{c.width}×{c.height} px — give a crop within the image")
            if t.image_dtype == "uint8" and c.bit_depth != 8:
                raise SpecError(f"{where}: training.image_dtype: uint8 cannot hold camera {c.name}'s {c.bit_depth}-"
                                "bit grey levels — write image_dtype = \"uint16\", or set the camera's bit_depth = 8")
            try:
                check_memory(f"cameras.{c.name}.size", c.size, v.scene.render.samples_per_pixel, True)
            except SceneError as exc:
                raise SpecError(f"{where}: {exc}") from None
    stereo = len(names) == 2
    labels = label_names(t.labels, indices, stereo) if t.labels else ()
    size = sample_bytes([first.camera(n) for n in names], t, labels, indices, stereo)
    per = max(1, t.shard_bytes // size)
    ids = [] if plan.sampled else [v.id for v in plan.variants]     # (a dry run's sample cuts no shards)
    shards = tuple(Shard(f"shard-{k:06d}.tar", tuple(ids[i:i + per])) for k, i in enumerate(range(0, len(ids), per)))
    return TrainingPlan(plan, t, names, indices, labels, size, per, shards)


def load_training(path: str | Path, sample: int | None = None) -> TrainingPlan:
    spec, spec_dir = read_spec(path)
    try:
        return expand_training(spec, spec_dir, sample)
    except SpecError as exc:
        raise SpecError(f"{path}: {exc}") from None


def is_training(spec) -> bool:
    return isinstance(spec, dict) and "training" in spec


def crop_offset(seed: int | None, index: int, size, crop) -> tuple[int, int]:
    """Where variant ``index``'s crop starts (x0, y0): drawn from the spec's seed and the index."""
    if crop is None:
        return 0, 0
    rng = np.random.default_rng(np.random.SeedSequence([seed or 0, index, 0x7261696E]))
    return int(rng.integers(0, size[0] - crop[0] + 1)), int(rng.integers(0, size[1] - crop[1] + 1))
