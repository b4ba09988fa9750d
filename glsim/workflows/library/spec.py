"""Library specs: a base scene plus ``[vary]``, expanded into checked variants before anything
is rendered or written.

A spec is a TOML file::

    scene = "bulge.toml"        # the base scene file (relative to the spec), or an inline [scene] table
    seed = 1                    # seed of every random draw (required when there is one)
    mode = "grid"               # grid: every combination; zip: i-th values together; random: n draws
    n = 10                      # random mode: the number of variants
    cameras = ["cam0", "cam1"]  # names or indices (default: every camera)
    steps = [0, 3]              # load steps, or "0-3" (default: every step)
    truth = true                # compact truth (element + ξ, η) per image
    truth_dtype = "float64"     # float64 (lossless) or float32

    [vary]                      # dotted paths into the scene → values
    noise.sigma = [0.5, 1.0, 2.0]                   # a list
    speckle.seed = {range = [0, 10]}                # start, stop[, step] (stop excluded)
    optics.f_number = {linspace = [2, 8, 4]}        # start, stop, count
    "cameras.1.pose.stereo.Phi" = {uniform = [25, 35], n = 3}   # draws: uniform, normal = [mean, std],
                                                    # integers = [lo, hi) , choice = [...]

Draws need ``n`` (how many values) in grid and zip modes; in random mode every key is drawn
afresh for each of the ``n`` variants (lists, ranges and linspaces by uniform choice). Each key
has its own random stream, seeded from ``seed`` and the key's name, so adding a key does not
change the others' values. A path's parts are table keys, list indices (``cameras.1``,
``lighting.lights.0``) or a camera's name (``cameras.cam1.fx``); missing tables are created
(``noise.sigma`` switches noise on).
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError, SceneError
from glsim.io.images import EXTENSIONS
from glsim.limits import MAX_IMAGES, MAX_VALUES, check_memory, check_nesting, not_a_file, parse_nested, parse_steps, refuse_count
from glsim.scene import Scene, scene_from_dict
from glsim.scene.load import from_resolved as _from_resolved
from glsim.workflows.library.keys import TRUTH_DIR, mesh_key, truth_keys

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

MODES = ("grid", "zip", "random")
SAMPLE_TAIL = 5       # expand(sample=n): the last variants built besides the first n − SAMPLE_TAIL
TOP_KEYS = ("scene", "seed", "mode", "n", "cameras", "steps", "truth", "truth_dtype", "vary")
LISTS = ("range", "linspace")
DRAWS = ("uniform", "normal", "integers", "choice")
GENERATORS = LISTS + DRAWS
TRUTH_DTYPES = ("float64", "float32")
INT64 = (-2 ** 63, 2 ** 63)   # the integers a spec may give: numpy draws integers = [low, high) in int64


class SpecError(GlsimError):
    """A spec that cannot be expanded: the message names the variant and key and the fix."""


def _fail(key: str, problem: str, fix: str) -> None:
    raise SpecError(f"{key}: {problem} — {fix}")


def _limit(key: str, count: int, limit: int, what: str, fix: str) -> None:
    """:func:`glsim.limits.refuse_count` as a SpecError."""
    try:
        refuse_count(key, count, limit, what, fix)
    except SceneError as exc:
        raise SpecError(str(exc)) from None


@dataclass(frozen=True)
class Variant:
    """One scene of the library: ``params`` maps each varied path to its value."""
    id: str
    index: int
    params: dict
    scene: Scene

    def label(self) -> str:
        return ", ".join(f"{k}={_show(v)}" for k, v in self.params.items())


@dataclass(frozen=True)
class Job:
    """One image: variant, camera name, load step and the files (relative to the library)."""
    variant: str
    camera: str
    step: int
    image: str
    truth: str           # "" without truth; else truth/{key}.truth, shared by the images of one truth key


@dataclass(frozen=True)
class LibraryPlan:
    """A spec expanded: every variant checked, every image named."""
    source: dict                  # the spec as read (with the base scene inlined)
    base_dir: str
    keys: tuple[str, ...]
    mode: str
    seed: int | None
    truth: bool
    truth_dtype: str
    cameras: tuple[str, ...]
    steps: tuple[int, ...]
    variants: tuple[Variant, ...]
    jobs: tuple[Job, ...]
    meshes: dict = field(default_factory=dict)     # specimen key → placed Mesh (checked)
    n_variants: int = 0                            # all variants; more than ``variants`` when sampled
    n_steps: dict = field(default_factory=dict)    # variant id → its specimen's load steps

    @property
    def sampled(self) -> bool:
        """Whether only some variants were expanded (``expand(..., sample=)``: a dry run's table)."""
        return self.n_variants > len(self.variants)

    def fingerprint(self) -> str:
        """SHA-256 of what the library holds: every variant's resolved scene, the images, truth."""
        h = hashlib.sha256()
        h.update(json.dumps({"truth": self.truth, "truth_dtype": self.truth_dtype, "keys": self.keys,
                             "jobs": [(j.variant, j.camera, j.step, j.image, j.truth) for j in self.jobs]},
                            sort_keys=True).encode())
        for v in self.variants:
            h.update(v.id.encode())
            h.update(json.dumps(v.params, sort_keys=True).encode())
            h.update(v.scene.to_json().encode())
        return h.hexdigest()

    def variant(self, vid: str) -> Variant:
        i = int(vid[1:])
        if i < len(self.variants) and self.variants[i].id == vid:
            return self.variants[i]
        return next(v for v in self.variants if v.id == vid)


def _show(v) -> str:
    return json.dumps(v) if not isinstance(v, float) else repr(v)


# ---- reading --------------------------------------------------------------------------------------

def read_spec(path: str | Path) -> tuple[dict, Path]:
    """The spec's table and its directory."""
    path = Path(path)
    why = not_a_file(path)
    if why:
        raise SpecError(f"{path}: {'spec file ' * (why == 'not found')}{why} — check the path (a library spec is a "
                        "TOML file)")
    try:
        data = parse_nested(tomllib.loads, path.read_text(encoding="utf-8"), str(path))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: is not a valid TOML file ({exc}) — fix the syntax there") from None
    except SceneError as exc:
        raise SpecError(str(exc)) from None
    return data, path.resolve().parent


def _base_scene(spec: dict, spec_dir: Path) -> tuple[dict, str]:
    """The base scene as a scene-file table and its base directory."""
    if "scene" not in spec:
        _fail("scene", "is required", 'give the base scene: scene = "bulge.toml" (relative to the spec) or an '
              "inline [scene] table with [[scene.cameras]], [scene.specimen], …")
    sc = spec["scene"]
    if isinstance(sc, dict):
        return copy.deepcopy(sc), str(spec_dir)
    if not isinstance(sc, str):
        _fail("scene", f"expected a file name or a table, got {sc!r}", 'write scene = "bulge.toml" or [scene]')
    p = Path(sc)
    p = p if p.is_absolute() else spec_dir / p
    why = not_a_file(p)
    if why:
        _fail("scene", f"file {p} {why}" if why == "not found" else f"{p} {why}",
              "check the path (relative paths start at the spec's directory)")
    if p.suffix == ".json":
        try:
            data, base = _from_resolved(parse_nested(json.loads, p.read_text(encoding="utf-8"), str(p)))
        except SceneError as exc:
            raise SpecError(f"scene: {exc}") from None
        except (ValueError, AttributeError, KeyError, TypeError) as exc:
            _fail("scene", f"{p} is not a scene.json written by glsim ({exc})", "give a TOML scene file")
        return data, base
    try:
        return parse_nested(tomllib.loads, p.read_text(encoding="utf-8"), str(p)), str(p.resolve().parent)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        _fail("scene", f"{p} is not a valid TOML file ({exc})", "fix the syntax there")
    except SceneError as exc:
        raise SpecError(f"scene: {exc}") from None


def _flatten(vary, prefix: str = "") -> list[tuple[str, object]]:
    """[vary] → [(dotted path, list or generator table)] in file order."""
    out = []
    for k, v in vary.items():
        path = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict) and not (set(v) & set(GENERATORS)):
            if not v:
                _fail(f"vary.{path}", "is an empty table", "give a list of values or a generator table")
            out += _flatten(v, path)
        else:
            out.append((path, v))
    return out


def _seed_for(seed: int, key: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(key.encode())]))


def _plain(v):
    if isinstance(v, np.generic):
        return v.item()
    return v


def _digits(n: int) -> str:
    """A long integer shown by its first 24 digits and its length."""
    text = str(n)
    return text if len(text) <= 24 else f"{text[:24]}… ({len(text)} digits)"


def _finite(x) -> bool:
    """A finite float, or an integer within ±2⁶³ (TOML's integers; math.isfinite overflows on larger ones)."""
    return INT64[0] <= x <= INT64[1] if isinstance(x, int) else math.isfinite(x)


def _numbers(key: str, name: str, value, count: int | tuple) -> list:
    counts = count if isinstance(count, tuple) else (count,)
    big = next((x for x in value if isinstance(x, int) and not _finite(x)), None) if isinstance(value, list) else None
    if big is not None:
        _fail(f"vary.{key}.{name}", f"{_digits(big)} is beyond 64-bit integers", "give numbers within ±2⁶³ (±9.2e18)")
    if (not isinstance(value, list) or len(value) not in counts
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and _finite(x) for x in value)):
        want = " or ".join(map(str, counts))
        _fail(f"vary.{key}.{name}", f"expected a list of {want} numbers, got {value!r}",
              {"range": "write range = [start, stop] or [start, stop, step]",
               "linspace": "write linspace = [start, stop, count]",
               "uniform": "write uniform = [low, high]", "normal": "write normal = [mean, std]",
               "integers": "write integers = [low, high] (high excluded)"}[name])
    return value


class _Key:
    """One varied path: its fixed values (lists, ranges) or its draw."""

    def __init__(self, path: str, value, mode: str, seed: int | None):
        self.path = path
        self.kind = "list"
        self.draw = None
        key = f"vary.{path}"
        if isinstance(value, list):
            if not value:
                _fail(key, "is an empty list", "give at least one value")
            self.values = list(value)
            return
        if not isinstance(value, dict):
            _fail(key, f"expected a list of values or a generator table, got {value!r}",
                  f"write e.g. {path} = [1, 2] or {path} = {{range = [0, 10]}}")
        gens = [g for g in GENERATORS if g in value]
        extra = sorted(set(value) - set(GENERATORS) - {"n"})
        if len(gens) != 1 or extra:
            _fail(key, f"has {', '.join(map(repr, gens + extra)) or 'no generator'}",
                  f"give exactly one of {', '.join(GENERATORS)} (and n for draws)")
        name = gens[0]
        arg = value[name]
        n = value.get("n")
        if name in LISTS:
            if n is not None:
                _fail(f"{key}.n", f"is not used with {name}", f"remove n; {name} gives its own values")
            if name == "range":
                a = _numbers(path, name, arg, (2, 3))
                start, stop, step = a[0], a[1], (a[2] if len(a) == 3 else 1)
                if step == 0 or (stop - start) / step <= 0:
                    _fail(f"{key}.range", f"{arg} gives no values", "give start < stop with a positive step")
                if not math.isfinite((stop - start) / step):   # float overflow: math.ceil would raise
                    _fail(f"{key}.range", f"{arg} spans more than a float can hold", "give a narrower range")
                count = math.ceil((stop - start) / step - 1e-9)
                _limit(f"{key}.range", count, MAX_VALUES, "values", "use a larger step or a narrower range")
                integer = all(isinstance(x, int) for x in (start, stop, step))
                self.values = [start + i * step if integer else float(start + i * step) for i in range(count)]
            else:
                a = _numbers(path, name, arg, 3)
                if not (isinstance(a[2], int) and a[2] >= 1):
                    _fail(f"{key}.linspace", f"count {a[2]!r} is not an integer ≥ 1", "write linspace = [2, 8, 4]")
                _limit(f"{key}.linspace", a[2], MAX_VALUES, "values", "give a smaller count")
                if not math.isfinite(a[1] - a[0]):   # float overflow: the values would be NaN
                    _fail(f"{key}.linspace", f"{arg} spans more than a float can hold", "give a narrower range")
                self.values = [float(x) for x in np.linspace(a[0], a[1], a[2])]
            return
        self.kind = "draw"
        if name == "choice":
            if not isinstance(arg, list) or not arg:
                _fail(f"{key}.choice", f"expected a non-empty list, got {arg!r}", "write choice = [3, 5, 7]")
        else:
            a = _numbers(path, name, arg, 2)
            if name == "uniform" and not a[0] < a[1]:
                _fail(f"{key}.uniform", f"low {a[0]} is not below high {a[1]}", "write uniform = [low, high]")
            if name == "uniform" and not math.isfinite(a[1] - a[0]):   # numpy's OverflowError
                _fail(f"{key}.uniform", f"{a} spans more than a float can hold", "give a narrower range")
            if name == "normal" and a[1] < 0:
                _fail(f"{key}.normal", f"std {a[1]} is negative", "write normal = [mean, std] with std ≥ 0")
            if name == "normal" and not math.isfinite(abs(a[0]) + 64 * a[1]):   # draws would overflow to inf
                _fail(f"{key}.normal", f"{a} reaches beyond what a float can hold", "give a smaller mean and std")
            if name == "integers" and not (all(isinstance(x, int) for x in a) and a[0] < a[1]):
                _fail(f"{key}.integers", f"{a} is not [low, high) with integers low < high",
                      "write integers = [0, 1000] (high excluded)")
        self.draw = (name, arg)
        if seed is None:
            _fail("seed", f"is required: vary.{path} is a random draw",
                  "add seed = 1 at the top of the spec (the same seed gives the same library)")
        if mode == "random":
            if n is not None:
                _fail(f"{key}.n", "is not used in random mode", "remove it; the top-level n sets the number of variants")
        else:
            if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
                _fail(f"{key}.n" if n is not None else key,
                      f"a {name} draw needs n (how many values) in {mode} mode" + (f", got {n!r}" if n is not None else ""),
                      "add n = 5 to the table, or use mode = \"random\"")
            _limit(f"{key}.n", n, MAX_VALUES, "values", "draw fewer values")
            self.values = self.sample(_seed_for(seed, path), n)

    def sample(self, rng: np.random.Generator, n: int) -> list:
        if self.draw is None:          # random mode over fixed values: uniform choice
            return [self.values[i] for i in rng.integers(0, len(self.values), n)]
        name, arg = self.draw
        if name == "uniform":
            return [float(x) for x in rng.uniform(arg[0], arg[1], n)]
        if name == "normal":
            return [float(x) for x in rng.normal(arg[0], arg[1], n)]
        if name == "integers":
            return [int(x) for x in rng.integers(arg[0], arg[1], n)]
        return [_plain(arg[i]) for i in rng.integers(0, len(arg), n)]


def _assign(data: dict, path: str, value) -> None:
    """Set ``path`` (dotted) in the scene table ``data``; missing tables are made."""
    parts = path.split(".")
    cur = data
    where = []
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(cur, list):
            if part.lstrip("-").isdigit():
                k = int(part)
                if not 0 <= k < len(cur):
                    _fail(f"vary.{path}", f"{'.'.join(where) or 'the scene'} has {len(cur)} entries "
                          f"(indices 0…{len(cur) - 1}), not {k}", "use an existing index")
            else:
                names = [c.get("name") if isinstance(c, dict) else None for c in cur]
                if part not in names:
                    _fail(f"vary.{path}", f"{'.'.join(where)} has no entry named {part!r}",
                          f"use an index 0…{len(cur) - 1}" + (f" or a name of {[n for n in names if n]}"
                                                              if any(names) else ""))
                k = names.index(part)
        elif isinstance(cur, dict):
            k = part
            if not last and k not in cur:
                if parts[i + 1].isdigit():
                    _fail(f"vary.{path}", f"{'.'.join(where + [part])} is not in the base scene", "vary an "
                          "existing list entry (add it to the base scene first)")
                cur[k] = {}
        else:
            _fail(f"vary.{path}", f"{'.'.join(where)} is a value ({cur!r}), not a table or list",
                  "the path must end at the value to vary")
        if last:
            cur[k] = value
        else:
            cur = cur[k]
        where.append(part)


def _steps(value) -> list[int] | None:
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return parse_steps(value, "steps")
        except SceneError as exc:
            raise SpecError(str(exc)) from None
    if isinstance(value, list) and value and all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        return list(value)
    _fail("steps", f"expected a list of load steps, got {value!r}", 'write steps = [0, 3] or "0-3"')


def expand(spec: dict, spec_dir: str | Path = ".", sample: int | None = None,
           keep_meshes: bool = True) -> LibraryPlan:
    """Expand and check a spec table (see the module text). Raises SpecError naming the key
    (and the variant) and the fix; reads every input the variants need (meshes, displacement
    files, noise tables) but writes nothing. Counts (values, variants, images) are checked
    against :mod:`glsim.limits` before anything is built. ``sample``: of more variants than that,
    only the first ``sample - SAMPLE_TAIL`` and the last SAMPLE_TAIL are built (a dry run's table).
    ``keep_meshes=False`` (a training set: no geometry files): each mesh is checked, then dropped."""
    from glsim.workflows.sequence import _check_effect_inputs
    from glsim.io.fe import specimen_mesh

    try:
        check_nesting(spec, "spec")
    except SceneError as exc:
        raise SpecError(str(exc)) from None
    unknown = sorted(set(spec) - set(TOP_KEYS))
    if unknown:
        import difflib
        close = difflib.get_close_matches(unknown[0], TOP_KEYS, 1)
        _fail(unknown[0], "unknown key", (f"did you mean {close[0]!r}? " if close else "")
              + f"a spec has {', '.join(TOP_KEYS)} (scene keys go in the base scene or [vary])")
    spec_dir = Path(spec_dir)
    base, base_dir = _base_scene(spec, spec_dir)
    mode = spec.get("mode", "grid")
    if mode not in MODES:
        _fail("mode", f"{mode!r} is not one of {MODES}", "grid: every combination; zip: values side by side; "
              "random: n random draws")
    seed = spec.get("seed")
    if seed is not None and not (isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0):
        _fail("seed", f"expected an integer ≥ 0, got {seed!r}", "write seed = 1")
    n = spec.get("n")
    if mode == "random":
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            _fail("n", f"random mode needs n ≥ 1 variants, got {n!r}", "add n = 10 at the top of the spec")
        if seed is None:
            _fail("seed", "is required in random mode", "add seed = 1 (the same seed gives the same library)")
        _limit("n", n, MAX_VALUES, "variants", "draw fewer variants")
    elif n is not None:
        _fail("n", f"is only used in random mode (mode is {mode!r})", "remove n, or set mode = \"random\"")
    truth = spec.get("truth", True)
    if not isinstance(truth, bool):
        _fail("truth", f"expected true or false, got {truth!r}", "write truth = true")
    dtype = spec.get("truth_dtype", "float64")
    if dtype not in TRUTH_DTYPES:
        _fail("truth_dtype", f"{dtype!r} is not one of {TRUTH_DTYPES}",
              "float64 is lossless; float32 is about 2.5× smaller (ξ, η within 3e-8)")
    vary = spec.get("vary", {})
    if not isinstance(vary, dict):
        _fail("vary", f"expected a table, got {vary!r}", "write [vary] with path = [values]")
    keys = [_Key(p, v, mode, seed) for p, v in _flatten(vary)]

    # the variants' values, counted before any is made
    if mode == "zip":
        lengths = {k.path: len(k.values) for k in keys}
        if len(set(lengths.values())) > 1:
            _fail("vary", f"zip mode needs lists of one length, got {', '.join(f'{p}: {m}' for p, m in lengths.items())}",
                  "give every key the same number of values, or use mode = \"grid\"")
    count = n if mode == "random" else math.prod(len(k.values) for k in keys) if mode == "grid" else \
        len(keys[0].values) if keys else 1
    _limit("vary", count, MAX_VALUES, "variants", "use fewer values or the random mode with a smaller n")
    cols = [k.sample(_seed_for(seed, k.path), n) if mode == "random" else k.values for k in keys]
    width = max(4, len(str(count - 1)))
    picked = range(count) if sample is None or count <= sample else \
        [*range(sample - SAMPLE_TAIL), *range(count - SAMPLE_TAIL, count)]

    cam_sel = spec.get("cameras")
    if cam_sel is not None and not (isinstance(cam_sel, list) and cam_sel
                                    and all(isinstance(c, (str, int)) and not isinstance(c, bool) for c in cam_sel)):
        _fail("cameras", f"expected a list of camera names or indices, got {cam_sel!r}", 'write cameras = ["cam0"]')
    steps = _steps(spec.get("steps"))

    variants, jobs, meshes, digests, n_steps = [], [], {}, {}, {}
    for i in picked:
        row = _row(mode, keys, cols, i)
        vid = f"v{i:0{width}d}"
        params = {k.path: _plain(v) for k, v in zip(keys, row)}
        data = copy.deepcopy(base)
        where = f"variant {vid}" + (f" ({', '.join(f'{p}={_show(v)}' for p, v in params.items())})" if params else "")
        try:
            for p, v in params.items():
                _assign(data, p, v)
            scene = scene_from_dict(data, base_dir)
        except SpecError as exc:
            raise SpecError(f"{where}: {exc}") from None
        except SceneError as exc:
            varied = [p for p in params if exc.key == p or exc.key.startswith(p + ".")
                      or _index_path(exc.key) == p or _index_path(exc.key).startswith(p + ".")]
            hint = f" (set by vary.{varied[0]})" if varied else ""
            raise SpecError(f"{where}: {exc}{hint}") from None
        names = [c.name for c in scene.cameras]
        cams = names if cam_sel is None else []
        for c in cam_sel or []:
            if isinstance(c, int):
                if not 0 <= c < len(names):
                    raise SpecError(f"{where}: cameras: index {c} does not exist (the scene has cameras 0…"
                                    f"{len(names) - 1}: {names}) — use one of them")
                c = names[c]
            elif c not in names:
                raise SpecError(f"{where}: cameras: no camera named {c!r} — use one of {names}")
            cams.append(c)
        if len(set(cams)) != len(cams):
            _fail("cameras", f"{cam_sel} names a camera twice", "list each camera once")
        mkey = mesh_key(scene)
        if mkey not in meshes:
            try:
                meshes[mkey] = specimen_mesh(scene)
            except SceneError as exc:
                raise SpecError(f"{where}: {exc}") from None
        nsteps = n_steps[vid] = meshes[mkey].n_steps
        if not keep_meshes:
            meshes = {mkey: meshes[mkey]}      # the last one only: consecutive variants often share it
        vsteps = list(range(nsteps)) if steps is None else steps
        for s in vsteps:
            if not 0 <= s < nsteps:
                raise SpecError(f"{where}: steps: step {s} does not exist (the specimen has steps 0…{nsteps - 1}) "
                                f"— use steps from 0…{nsteps - 1}")
        try:
            _check_effect_inputs(scene, [scene.camera(c) for c in cams])
            for c in cams:
                check_memory(f"cameras.{c}.size", scene.camera(c).size, scene.render.samples_per_pixel, truth)
        except SceneError as exc:
            raise SpecError(f"{where}: {exc}") from None
        if truth and scene.sensor is not None and scene.sensor.line_time > 0 and not scene.exposure.rigid:
            raise SpecError(f"{where}: sensor.line_time: a rolling shutter exposes each row at its own time, and "
                            "a library's truth files make the rows' states from a rigid motion only (here they "
                            "interpolate between load steps) — give exposure.velocity or angular_velocity, write "
                            "truth = false, or render the rolling shutter's truth with `glsim render --truth`")
        ext = EXTENSIONS[scene.output.format]
        tkeys = truth_keys(scene, meshes[mkey], cams, vsteps, dtype, digests) if truth else {}
        for s in vsteps:
            for c in cams:
                image = f"{vid}/" + scene.output.pattern.format(camera=c, step=s, ext=ext)
                jobs.append(Job(vid, c, s, image, f"{TRUTH_DIR}/{tkeys[c, s]}.truth" if truth else ""))
        variants.append(Variant(vid, i, params, scene))
        _limit("vary", len(jobs) * count // len(variants), MAX_IMAGES, "images (variants × cameras × steps)",
                     "use fewer variants, cameras or steps")
    if not jobs:
        _fail("cameras", "no image to render", "select at least one camera and step")
    all_steps = tuple(sorted({j.step for j in jobs}))
    all_cams = tuple(dict.fromkeys(j.camera for j in jobs))
    return LibraryPlan(source={**spec, "scene": base} if not isinstance(spec.get("scene"), dict) else dict(spec),
                base_dir=base_dir, keys=tuple(k.path for k in keys), mode=mode, seed=seed, truth=truth,
                truth_dtype=dtype, cameras=all_cams, steps=all_steps, variants=tuple(variants), jobs=tuple(jobs),
                meshes=meshes if keep_meshes else {}, n_variants=count, n_steps=n_steps)


def _row(mode: str, keys: list, cols: list, i: int) -> tuple:
    """Variant ``i``'s values: grid rows in itertools.product order (the last key fastest)."""
    if mode != "grid":
        return tuple(c[i] for c in cols)
    row = []
    for k in reversed(keys):
        i, r = divmod(i, len(k.values))
        row.append(k.values[r])
    return tuple(reversed(row))


def _index_path(key: str) -> str:
    """``cameras[1].pose.stereo.Phi`` → ``cameras.1.pose.stereo.Phi``."""
    return key.replace("[", ".").replace("]", "")


def load_plan(path: str | Path, sample: int | None = None) -> LibraryPlan:
    """Read and expand a spec file (``sample``: see :func:`expand`)."""
    spec, spec_dir = read_spec(path)
    try:
        return expand(spec, spec_dir, sample)
    except SpecError as exc:
        raise SpecError(f"{path}: {exc}") from None
