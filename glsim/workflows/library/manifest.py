"""The library's index: ``manifest.csv`` (one row per image) and ``library.json`` (the spec,
its expansion and fingerprint), both written atomically so that an interrupted run leaves
files that load.

Columns of ``manifest.csv``, in order:

==================  ==========================================================================
``variant``         variant id (``v0000`` …; its folder holds ``scene.json``, images, truth)
one per vary key    the value of each varied parameter, named by its dotted path
``camera``          camera name
``step``            load step
``file``            the image, relative to the library root
``bytes``           its size
``sha256``          its SHA-256 (hex)
``truth_file``      the compact truth, ``truth/{key}.truth`` (shared by the images of one truth
                    key, :func:`.keys.truth_keys`); empty without truth
``truth_bytes``     its size (0 without truth)
``truth_sha256``    its SHA-256 (empty without truth)
``render_s``        seconds the render took (with GL truth read-back when truth is on)
``truth_s``         seconds encoding the compact truth (0 for an image whose truth file another
                    image wrote)
``encode_s``        seconds encoding the image (quantise, TIFF/PNG, hash)
``write_s``         seconds writing both files
``saturated``       fraction of the specimen's pixels clipped when quantised (the background,
                    noisy around 0, is not counted)
``covered``         fraction of the image's pixels on the specimen (0: the camera sees none of
                    it, and the render warned why)
==================  ==========================================================================

Values of varied parameters are JSON (numbers as Python writes them, strings quoted, lists
as lists). Rows are sorted by variant, camera (in scene order) and step, so a library
rendered with any number of workers has the same manifest apart from the timing columns.
"""
from __future__ import annotations

import csv
import io as _io
import json
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.limits import parse_nested, read_bounded

FILE_COLUMNS = ("camera", "step", "file", "bytes", "sha256", "truth_file", "truth_bytes", "truth_sha256")
TIME_COLUMNS = ("render_s", "truth_s", "encode_s", "write_s", "saturated", "covered")
MANIFEST = "manifest.csv"
LIBRARY = "library.json"
GEOMETRY_DIR = "geometry"
VERSION = 2          # of library.json; 1: one truth file per image, beside it


def columns(keys) -> list[str]:
    return ["variant", *keys, *FILE_COLUMNS, *TIME_COLUMNS]


def manifest_text(plan, records: dict) -> str:
    """The CSV of ``records`` ((variant, camera, step) → record), in the plan's job order."""
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns(plan.keys))
    for job in plan.jobs:
        rec = records.get((job.variant, job.camera, job.step))
        if rec is None:
            continue
        params = plan.variant(job.variant).params
        w.writerow([job.variant, *(json.dumps(params[k]) for k in plan.keys),
                    *(rec[c] for c in FILE_COLUMNS),
                    *(f"{rec[c]:.6g}" if isinstance(rec.get(c), float) else rec.get(c, "") for c in TIME_COLUMNS)])
    return buf.getvalue()


def write_manifest(out: Path, plan, records: dict) -> Path:
    return io.write_text(out / MANIFEST, manifest_text(plan, records))


class ManifestError(GlsimError):
    """``manifest.csv`` cannot be read as text rows (the message names the file, where, and the fix)."""


def manifest_rows(out: Path) -> list[dict]:
    """The rows of ``manifest.csv`` as the CSV holds them (column → text; empty if there is no
    manifest), each with ``_line``, its (last) line number (the header is line 1). ManifestError for a
    file that is not UTF-8 text or not CSV (a field over the csv module's 128 KiB limit)."""
    path = Path(out) / MANIFEST
    if not path.is_file():
        return []
    fix = ("the manifest is damaged: restore it, or delete it and run the library command again (its images "
           "are then rendered again)")
    try:
        text = read_bounded(path).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ManifestError(f"{path}: is not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}) "
                            f"— {fix}") from None
    except OSError as exc:
        raise ManifestError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    lines = counted(text.splitlines(keepends=True))
    reader = csv.DictReader(lines)
    rows = []
    try:
        for row in reader:
            rows.append({**row, "_line": lines.count})
    except csv.Error as exc:
        raise ManifestError(f"{path}: line {lines.count} is not CSV ({exc}) — {fix}") from None
    return rows


class counted:
    """An iterator over ``lines`` that counts those taken (the line a csv reader is on)."""

    def __init__(self, lines):
        self.lines, self.count = iter(lines), 0

    def __iter__(self):
        return self

    def __next__(self):
        line = next(self.lines)
        self.count += 1
        return line


def record(row: dict) -> dict:
    """A manifest row as a record: step and sizes as int, the time columns as float (NaN if
    empty). ValueError, KeyError or TypeError for a row that does not read so."""
    rec = {k: v for k, v in row.items() if k != "_line"}
    rec["step"] = int(rec["step"])
    rec["bytes"] = int(rec["bytes"])
    rec["truth_bytes"] = int(rec["truth_bytes"] or 0)
    for c in TIME_COLUMNS:
        rec[c] = float(rec[c]) if rec.get(c) not in (None, "") else float("nan")
    return rec


def read_manifest(out: Path) -> dict:
    """(variant, camera, step) → record, from ``manifest.csv`` (empty if there is none; rows
    that do not read are left out: their images are rendered again). ManifestError as
    :func:`manifest_rows`."""
    records = {}
    for row in manifest_rows(out):
        try:
            rec = record(row)
        except (KeyError, ValueError, TypeError):
            continue
        records[(rec["variant"], rec["camera"], rec["step"])] = rec
    return records


def library_info(plan, fingerprint: str) -> dict:
    return {"format": "glsim-library", "version": VERSION, "fingerprint": fingerprint, "spec": plan.source,
            "base_dir": plan.base_dir, "mode": plan.mode, "seed": plan.seed, "keys": list(plan.keys),
            "truth": plan.truth, "truth_dtype": plan.truth_dtype, "cameras": list(plan.cameras),
            "steps": list(plan.steps), "columns": columns(plan.keys),
            "variants": [{"id": v.id, "params": v.params} for v in plan.variants],
            "images": len(plan.jobs),
            "jobs": [[j.variant, j.camera, j.step, j.image, j.truth] for j in plan.jobs]}


class StoredPlan:
    """What ``library.json`` says the library holds (the keys, variants and images), enough to
    check and index it without the spec's inputs."""

    def __init__(self, info: dict):
        from glsim.workflows.library.spec import Job

        self.keys = tuple(info["keys"])
        self.params = {v["id"]: v["params"] for v in info["variants"]}
        self.jobs = tuple(Job(*j) for j in info["jobs"])

    def variant(self, vid: str):
        return _Params(self.params[vid])


class _Params:
    def __init__(self, params):
        self.params = params


def write_library_info(out: Path, info: dict) -> Path:
    """``library.json``, its tables in the order given: the spec's [vary] keys keep their order,
    which the variants' expansion (and so the fingerprint a resume compares) follows."""
    return io.write_text(out / LIBRARY, json.dumps(info, indent=1) + "\n")


def read_library_info(out: Path) -> dict | None:
    """``library.json`` of the library in ``out``; None if there is none, or a damaged one."""
    try:
        data = parse_nested(json.loads, read_bounded(Path(out) / LIBRARY).decode("utf-8"), LIBRARY)
    except (OSError, ValueError, UnicodeDecodeError):    # SceneError (nested too deep) is a ValueError
        return None
    return data if isinstance(data, dict) and data.get("format") == "glsim-library" and _complete(data) else None


def _complete(info: dict) -> bool:
    """Whether ``info`` has every field of :func:`library_info` that resume and verify read, with
    jobs of known variants and files inside the library."""
    text = lambda v: isinstance(v, str)  # noqa: E731
    inside = lambda p: text(p) and not Path(p).is_absolute() and ".." not in Path(p).parts  # noqa: E731
    try:
        ids = {v["id"] for v in info["variants"] if text(v["id"]) and isinstance(v["params"], dict)}
        return (isinstance(info["spec"], dict) and text(info["base_dir"]) and all(map(text, info["keys"]))
                and len(ids) == len(info["variants"]) and all(
                    isinstance(j, list) and len(j) == 5 and j[0] in ids and text(j[1]) and isinstance(j[2], int)
                    and inside(j[3]) and (j[4] == "" or inside(j[4])) for j in info["jobs"]))
    except (KeyError, TypeError):
        return False
