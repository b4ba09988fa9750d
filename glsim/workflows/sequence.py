"""Render a scene's cameras over its load steps into a directory: images, truth and the
resolved ``scene.json``.

Rules of the output directory (README "Output directory"):

* Nothing is written until the whole scene and every input it names (mesh, displacement files,
  reference image, noise table) has been read and checked, and the steps and cameras asked for
  exist: an error leaves the directory as it was (and creates none).
* A directory that is not empty must hold a render of the same scene (its ``scene.json`` equal
  to this one): the render then resumes, keeping the images (with their truth) already there
  whose bytes match what ``render-manifest.jsonl`` recorded as written
  (:mod:`glsim.io.rendermanifest`); any other is rendered again, and the temporaries of its own
  files that a killed run left are removed. Anything else is refused unless ``force``: then the
  images and truth of the render there are removed first (other files are kept) and everything
  is rendered anew.
* Every file name is checked before the first is written: ``output.pattern`` formatted with the
  real cameras and steps gives no two files one name, none leaves the directory, and nothing but
  a regular file (no link, directory or FIFO) is where a file goes.
* An image and its truth maps appear together or not at all (see
  :func:`glsim.io.images.write_image_with_truth`).
* One run writes a directory at a time, and only inside it (:mod:`glsim.io.outdir`).
* For a time-series mesh (Exodus II, .pvd, XDMF) ``steps.json`` beside ``scene.json`` gives
  the solver's time of each load step (null for an undeformed step 0 glsim put in front).
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import stat
import string
from dataclasses import dataclass
from pathlib import Path

from glsim.errors import SceneError
from glsim.io import atomic, outdir, rendermanifest
from glsim.io import images as io
from glsim.limits import parse_nested
from glsim.render import Renderer, Truth
from glsim.scene import Scene
from glsim.scene.model import check_output_names


@dataclass(frozen=True)
class Written:
    """What :func:`write_sequence` wrote: image paths, truth paths and seconds per render;
    ``kept``: images of an earlier run of the same scene that were already there (their bytes
    those recorded in its manifest)."""
    images: tuple[str, ...]
    truth: tuple[str, ...]
    seconds: tuple[float, ...]
    saturated: tuple[float, ...]      # per image: fraction of pixels clipped when written
    scene_json: str
    kept: tuple[str, ...] = ()
    removed: tuple[str, ...] = ()     # files of an earlier render removed by force=True
    redone: tuple[str, ...] = ()      # "image: why": rendered again, a file there not matching the manifest
    swept: tuple[str, ...] = ()       # temporaries an interrupted run left, removed


@dataclass(frozen=True)
class _Image:
    """One image to write: its camera, step, path and its truth files' paths."""
    camera: str
    step: int
    path: Path
    truth: tuple[Path, ...]


def write_sequence(scene: Scene, directory: str | None = None, steps=None, cameras=None,
                   backend: str | None = None, truth: bool = False, progress=None,
                   truth_format: str = "npz", force: bool = False) -> Written:
    """Render every camera at every step and write the images (and truth maps) atomically.

    ``backend`` overrides ``[render] backend`` (and is recorded in ``scene.json``). Truth maps
    go to one ``*_truth.npz`` per image, or with ``truth_format="tiff"`` (float32) or
    ``"tiff64"`` (float64) to one TIFF per map. ``force`` replaces a render of another scene
    in ``directory`` (see the module text). ``progress(done, total, path)`` is called after
    each image. Returns what was written.
    """
    if truth_format not in io.TRUTH_FORMATS:
        raise SceneError("truth_format", f"{truth_format!r} is not one of {io.TRUTH_FORMATS}",
                         f"use one of {', '.join(io.TRUTH_FORMATS)}")
    if backend and backend != scene.render.backend:
        scene = scene.replace(render={"backend": backend})
    out = Path(directory or scene.resolve(scene.output.directory))
    with outdir.locked(out):
        return _write(scene, out, steps, cameras, truth, progress, truth_format, force)


def _write(scene: Scene, out: Path, steps, cameras, truth: bool, progress, truth_format: str,
           force: bool) -> Written:
    """:func:`write_sequence` holding the lock of ``out``."""
    resume = _check_directory(out, scene, force)
    with Renderer(scene) as r:                      # reads and checks mesh, steps' files, reference
        n = r.mesh.n_steps
        steps = list(range(n)) if steps is None else list(steps)
        for s in steps:
            if not 0 <= s < n:
                raise SceneError("steps", f"step {s} does not exist (the scene has steps 0…{n - 1})",
                                 f"use steps from 0…{n - 1}, e.g. --steps 0-{n - 1}")
        cams = [scene.camera(c) for c in (cameras if cameras is not None else range(len(scene.cameras)))]
        _once("steps", "step", steps)
        _once("cameras", "camera", [c.name for c in cams])
        _check_effect_inputs(scene, cams)
        for cam in cams:
            r.check_size(cam.name, truth)
        maps = Truth.FIELDS + (Truth.MOTION if scene.exposure is not None else ())   # the maps a truth file holds
        todo, others = _plan(scene, out, steps, cams, maps if truth else None, truth_format, r.mesh)
        keep, redone = _verify(out, todo) if resume else (set(), [])
        # Everything is read and checked: from here on files are written.
        with _writing(out):
            removed = _clear(out, scene) if force and not resume else []
            swept = _sweep(out, [i.path for i in todo] + [p for i in todo for p in i.truth] + others)
        with _writing(out / "scene.json"):
            scene_json = io.write_text(out / "scene.json", scene.to_json())
        with _writing(out):
            _write_extras(scene, out, cams, r.mesh, truth and truth_format == "vtk")
        done = _render_images(r, scene, out, todo, keep, truth, truth_format, progress)
    return Written(*done, str(scene_json), tuple(str(i.path) for i in todo if i.path in keep),
                   tuple(map(str, removed)), tuple(redone), tuple(map(str, swept)))


def _render_images(r: Renderer, scene: Scene, out: Path, todo, keep, truth: bool, truth_format: str, progress):
    """Render and write each image of ``todo`` not in ``keep`` (with its truth), each recorded in the
    render's manifest once written; (images, truth files, seconds, saturated fractions)."""
    images, truths, seconds, saturated = [], [], [], []
    with contextlib.ExitStack() as stack:
        with _writing(out / rendermanifest.NAME):
            record = stack.enter_context(rendermanifest.appending(out))
        for k, item in enumerate(todo):
            if item.path not in keep:
                res = r.render(item.camera, item.step, truth=truth)
                with _writing(item.path):
                    img, tps = io.write_image_with_truth(item.path, res.image, scene.camera(item.camera).bit_depth,
                                                         scene.output.format, res.truth.as_dict() if truth else None,
                                                         truth_format)
                with _writing(out / rendermanifest.NAME):
                    record([*tps, img])
                images.append(str(img))
                truths += map(str, tps)
                seconds.append(res.seconds)
                saturated.append(res.saturated)
            if progress:
                progress(k + 1, len(todo), str(item.path))
    return tuple(images), tuple(truths), tuple(seconds), tuple(saturated)


def _once(key: str, what: str, items) -> None:
    """SceneError(key) if an item is asked for twice (it would be rendered twice into one file)."""
    seen = set()
    for item in items:
        if item in seen:
            raise SceneError(key, f"{what} {item} is asked for twice", f"name each {what} once")
        seen.add(item)


def _plan(scene: Scene, out: Path, steps, cams, maps, truth_format: str, mesh) -> tuple[list[_Image], list[Path]]:
    """The images to write (step by step, camera by camera; ``maps``: the truth maps, None for no
    truth) and the other files a render writes, their names checked: none shared by two files
    (output.pattern formatted with the real cameras and steps), none leaving ``out``, none where
    something other than a regular file is (a link, a directory)."""
    ext = io.EXTENSIONS[scene.output.format]
    files, todo = [], []
    for step in steps:
        for cam in cams:
            rel = scene.output.pattern.format(camera=cam.name, step=step, ext=ext)
            tps = [p.as_posix() for p in io.truth_paths(rel, maps, truth_format)] if maps is not None else []
            files += [(rel, f"the image of camera {cam.name} at step {step}")]
            files += [(t, f"the truth of camera {cam.name} at step {step} ({Path(t).name})") for t in tps]
            todo.append((cam.name, step, rel, tps))
    own = _own_files(scene, cams, mesh, truth_format, maps)
    files += [(name, f"{name} (glsim's own)") for name in own]
    check_output_names(scene.output.pattern, files)
    paths = dict(zip([f for f, _ in files], outdir.inside(out, [f for f, _ in files], "output.pattern")))
    for rel, what in files:
        _check_target(paths[rel], what)
    images = [_Image(c, s, paths[rel], tuple(paths[t] for t in tps)) for c, s, rel, tps in todo]
    return images, [paths[f] for f in own]


def _own_files(scene: Scene, cams, mesh, truth_format: str, maps) -> list[str]:
    """The names of the files a render writes besides images and truth."""
    names = ["scene.json", rendermanifest.NAME]
    if scene.vignetting is not None and scene.vignetting.flat_field:
        names += [p.as_posix() for cam in cams for p in io.truth_tiff_paths(cam.name, ["flatfield"])]
    if maps is not None and truth_format == "vtk":
        names += [f"mesh_{k:04d}.vtu" for k in range(mesh.n_steps)] + ["mesh.pvd"]
    if mesh.step_times:
        names.append("steps.json")
    return names


def _check_target(path: Path, what: str) -> None:
    """SceneError naming ``path`` if something other than a regular file is there (a link, a
    directory, a FIFO): glsim neither writes through nor replaces it."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        raise SceneError(str(path), f"is {atomic.kind(mode)}, where glsim writes {what}",
                         "remove it, or write to another directory (-o)")


def _write_extras(scene: Scene, out: Path, cams, mesh, vtk: bool) -> None:
    """Flat fields, the FE mesh for ParaView, the steps' times: what a render writes besides images."""
    if scene.vignetting is not None and scene.vignetting.flat_field:   # each camera's gain: {camera}_flatfield.tif
        from glsim.effects.vignetting import flat_field
        for cam in cams:
            io.write_truth_tiff(out / cam.name, {"flatfield": flat_field(cam, scene.vignetting)})
    if vtk:                                         # the FE mesh beside the .vti truth, for ParaView
        from glsim.io.vtkfiles import write_mesh_series
        write_mesh_series(out, mesh, scene.cameras[0])
    if mesh.step_times:                             # a time series: the solver's time of each step
        io.write_text(out / "steps.json", json.dumps({"steps": [
            {"step": k, "time": t} for k, t in enumerate(mesh.step_times)]}))


def _verify(out: Path, todo) -> tuple[set[Path], list[str]]:
    """The images of ``todo`` to keep on resuming — each of their files a regular file whose bytes
    match the render's manifest — and "image: why" of those there that do not (rendered again)."""
    rel = lambda f: f.relative_to(out).as_posix()  # noqa: E731
    groups = [(i.path, [*i.truth, i.path]) for i in todo]
    present = [(image, fs) for image, fs in groups if all(os.path.isfile(f) for f in fs)]
    records = rendermanifest.read(out, [rel(f) for _, fs in present for f in fs])
    keep, redone = set(), []
    for image, fs in present:
        why = next((f"{rel(f)}: {w}" for f in fs if (w := rendermanifest.mismatch(f, records.get(rel(f))))), "")
        if why:
            redone.append(why)
        else:
            keep.add(image)
    return keep, redone


def _sweep(out: Path, paths) -> list[Path]:
    """Remove the temporaries (:func:`glsim.io.atomic.temporary_of`) of ``paths`` that an
    interrupted run left: only those, in their folders; no other file."""
    names: dict[Path, set[str]] = {}
    for p in paths:
        names.setdefault(p.parent, set()).add(p.name)
    swept = []
    for folder, wanted in names.items():
        if not folder.is_dir():
            continue
        for entry in os.scandir(folder):
            if atomic.temporary_of(entry.name) in wanted and entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
                swept.append(Path(entry.path))
    return sorted(swept)


@contextlib.contextmanager
def _writing(path: Path):
    """An OSError while writing (a full disk, a read-only filesystem) as a WriteError naming the
    file — the temporary's final name — and how to go on."""
    try:
        yield
    except OSError as exc:
        name = Path(exc.filename2 or exc.filename or path)
        name = name.with_name(atomic.temporary_of(name.name) or name.name)
        full = exc.errno in (errno.ENOSPC, errno.EDQUOT)
        raise outdir.WriteError(f"{name}: cannot be written ({outdir.problem(exc)}) — "
                                + ("free space" if full else "check that the output directory is writable")
                                + ", then run the same command again to resume") from None


def _check_effect_inputs(scene: Scene, cams) -> None:
    """Read the files the effects need at render time (the noise variance table, the PSF kernel:
    a measured PSF's checks)."""
    nz = scene.noise
    if nz is not None and nz.model == "heteroscedastic":
        from glsim.effects import noise as noisemod
        for bits in sorted({c.bit_depth for c in cams}):
            noisemod.load_variance_table(scene.resolve(nz.variance_file), bits)
    if scene.psf is not None:
        from glsim.effects.psf import make_kernel
        make_kernel(scene.psf, Path(scene.base_dir))


# --- the output directory ----------------------------------------------------------------------

FORCE_FIX = ("write to a new directory (-o), or pass --force (force=True) to replace the render there "
             "(its images and truth are removed first; other files are kept)")


def _check_directory(out: Path, scene: Scene, force: bool) -> bool:
    """True to resume a render of the same scene in ``out``; False for a new render. Raises
    SceneError for a directory holding something else, unless ``force``."""
    if not [p for p in outdir.entries(out) if atomic.temporary_of(p.name) is None]:   # a run killed at once: new
        return False
    old = _read_json(out / "scene.json")
    new = json.loads(scene.to_json())
    if old == new:
        return not force
    if force:
        return False
    if old is None and (out / "scene.json").exists():
        problem = "holds a scene.json that is not glsim's"
    elif old is None:
        names = sorted(p.name for p in outdir.entries(out))
        shown = ", ".join(names[:3]) + (", …" if len(names) > 3 else "")
        problem = f"is not empty ({len(names)} entries: {shown}) and holds no scene.json of a render"
    else:
        problem = f"holds a render of another scene (scene.json differs: {_first_difference(old, new)})"
    raise SceneError(str(out), problem, FORCE_FIX)


MAX_SCENE_JSON = 1 << 24      # bytes of a scene.json read to compare (glsim's are a few kB)


def _read_json(path: Path):
    """The table in the regular file ``path`` (not followed if a link; at most MAX_SCENE_JSON
    bytes, nested at most MAX_NESTING deep), else None."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_SCENE_JSON:
            return None
        try:
            data = parse_nested(json.loads, f.read(MAX_SCENE_JSON).decode("utf-8"), str(path))
        except (OSError, ValueError):         # SceneError and UnicodeDecodeError are ValueErrors
            return None
    return data if isinstance(data, dict) else None


def _first_difference(old, new, key: str = "") -> str:
    """The first key whose value differs, as ``key: X there, Y now``."""
    if isinstance(old, dict) and isinstance(new, dict):
        for k in list(new) + [k for k in old if k not in new]:
            if old.get(k, _MISSING) != new.get(k, _MISSING):
                return _first_difference(old.get(k, _MISSING), new.get(k, _MISSING), f"{key}.{k}" if key else k)
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new)):
            if a != b:
                return _first_difference(a, b, f"{key}[{i}]")
    show = lambda v: "absent" if v is _MISSING else _short(v)  # noqa: E731
    return f"{key or 'the scene'} is {show(old)} there, {show(new)} now"


_MISSING = object()


def _short(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "…"


def _image_regex(data: dict) -> re.Pattern:
    """The relative paths of the images a scene (as in its scene.json) names, as a regex."""
    output = data.get("output") or {}
    pattern = output.get("pattern", "{camera}_{step:04d}.{ext}")
    ext = io.EXTENSIONS.get(output.get("format", "tiff"), "tif")
    names = [c.get("name", "") for c in data.get("cameras", []) if isinstance(c, dict)]
    fields = {"camera": "(?:" + "|".join(map(re.escape, names or ["[^/]+"])) + ")", "step": r"-?\d+",
              "ext": re.escape(ext)}
    regex = ""
    for literal, field, _, _ in string.Formatter().parse(pattern):
        regex += re.escape(literal) + (fields.get(field, "[^/]*") if field is not None else "")
    return re.compile(regex)


def _is_output(rel: str, regexes) -> bool:
    """Whether ``rel`` (relative posix path) is an image, truth file or leftover temporary of them."""
    parent, _, name = rel.rpartition("/")
    if name.startswith(".") and ".part" in name:          # a temporary of an interrupted write
        name = name[1:].rpartition(".part")[0].rpartition(".")[0]
    if not parent and re.fullmatch(r"mesh(_\d{4}\.vtu|\.pvd)", name):   # --truth-format vtk's FE mesh
        return True
    candidates = [name]
    stem, sep, _ = name.rpartition("_truth")
    if sep:
        candidates += [f"{stem}.{e}" for e in io.EXTENSIONS.values()]
    return any(rx.fullmatch(f"{parent}/{c}" if parent else c) for rx in regexes for c in candidates)


def _clear(out: Path, scene: Scene) -> list[Path]:
    """What ``force`` removes: the images and truth of the render in ``out`` (returned) and its
    manifest."""
    removed = _remove_previous(out, scene)
    if os.path.lexists(out / rendermanifest.NAME):          # (a regular file: checked with the targets)
        os.unlink(out / rendermanifest.NAME)
    return removed


def _remove_previous(out: Path, scene: Scene) -> list[Path]:
    """Remove the images, truth files and temporaries of the render in ``out`` (as named by its
    scene.json, and by this scene); other files stay."""
    if not out.is_dir():
        return []
    regexes = [_image_regex(json.loads(scene.to_json()))]
    old = _read_json(out / "scene.json")
    if old is not None:
        regexes.append(_image_regex(old))
    removed = []
    for p in sorted(out.rglob("*")):
        if p.is_file() and _is_output(p.relative_to(out).as_posix(), regexes):
            os.unlink(p)
            removed.append(p)
    return removed
