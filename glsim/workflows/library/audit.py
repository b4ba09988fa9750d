"""Which of a library's files are good, and ``verify``: the whole directory checked against the
spec it stores (``glsim library DIR --verify``). A run (:mod:`.runner`) keeps the good files
when it resumes and renders the rest.

* An image is good if its manifest row names its files and it has the row's size and SHA-256.
* Truth is content-addressed (``truth/{key}.truth``, :func:`.keys.truth_keys`). A truth file is
  good if it has the size and SHA-256 its manifest rows give, or, where no row gives them yet
  (written after the last manifest update), if it decodes: its name is its key, and it was
  renamed into place whole.
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import truth as truthio
from glsim.io.hashes import sha256_file
from glsim.workflows.library import manifest as mf
from glsim.workflows.library.spec import LibraryPlan

TRUTH_BAD = "truth missing or fails its size/SHA-256"


class LibraryError(GlsimError):
    """The library directory cannot be used as asked (the message says why and the fix)."""


def first_difference(old: dict, plan: LibraryPlan) -> str:
    """The first way stored library info ``old`` (library.json) differs from ``plan``'s, in words."""
    new = mf.library_info(plan, "")
    if old.get("version") != new["version"]:
        return f"it was written by an older glsim (library version {old.get('version')}, one truth file per image)"
    for key in ("keys", "mode", "seed", "truth", "truth_dtype", "cameras", "steps", "images"):
        if old.get(key) != new.get(key):
            return f"{key} is {json.dumps(old.get(key))} there, {json.dumps(new.get(key))} now"
    ov, nv = old.get("variants", []), new["variants"]
    if len(ov) != len(nv):
        return f"{len(ov)} variants there, {len(nv)} now"
    for a, b in zip(ov, nv):
        if a != b:
            return f"variant {b['id']} has {json.dumps(a.get('params'))} there, {json.dumps(b['params'])} now"
    oj, nj = old.get("jobs", []), new["jobs"]
    if oj != nj and [j[:4] for j in oj] == [j[:4] for j in nj]:
        return ("its truth files are of another compact-truth format (written by another glsim version; "
                "--force re-renders them with this one)")
    return "the base scene differs"


def _file_ok(path: Path, size: int, sha: str) -> bool:
    try:
        return path.stat().st_size == size and sha256_file(path) == sha
    except OSError:
        return False


def check_records(out: Path, plan: LibraryPlan, records: dict) -> tuple[dict, list, dict]:
    """The records whose files are good, a list of problems (job, what) for every other image
    of the plan, and the good truth files (path → (bytes, SHA-256); see the module text for
    the rule). Each file is hashed once, on a few threads."""
    from concurrent.futures import ThreadPoolExecutor

    rows: dict[str, list] = {}
    for job in plan.jobs:
        rec = records.get((job.variant, job.camera, job.step))
        if job.truth:
            rows.setdefault(job.truth, []).extend([rec] if rec and rec.get("truth_file") == job.truth else [])
    with ThreadPoolExecutor(max_workers=min(8, (os.cpu_count() or 1) + 2)) as pool:
        truths = dict(zip(rows, pool.map(lambda path: _truth_status(out, path, rows[path]), rows)))
        results = list(pool.map(lambda job: _check_job(out, job, records, truths), plan.jobs))
    good, problems = {}, []
    for job, (rec, what) in zip(plan.jobs, results):
        if what:
            problems.append((job, what))
        else:
            good[(job.variant, job.camera, job.step)] = rec
    return good, problems, {path: t for path, t in truths.items() if t}


def _truth_status(out: Path, path: str, rows: list) -> tuple[int, str] | None:
    """(bytes, SHA-256) of the truth file ``path`` if it is good (see the module text), else None."""
    row = next((r for r in rows if r.get("truth_sha256")), None)
    if row is not None:
        ok = _file_ok(out / path, row["truth_bytes"], row["truth_sha256"])
        return (row["truth_bytes"], row["truth_sha256"]) if ok else None
    try:
        truthio.read(out / path).xi            # the header, the element map and (ξ, η) decode
        return (out / path).stat().st_size, sha256_file(out / path)
    except (GlsimError, OSError):
        return None


def _check_job(out: Path, job, records: dict, truths: dict) -> tuple[dict | None, str]:
    """(the job's record, "") if its files are good, else (None, what is wrong)."""
    rec = records.get((job.variant, job.camera, job.step))
    if rec is None:
        return None, ("no manifest row" if not (out / job.image).exists() else
                      "image present but not in the manifest (written after its last update)")
    if rec.get("file") != job.image or rec.get("truth_file", "") != job.truth:
        return None, "manifest row names other files"
    if not _file_ok(out / job.image, rec["bytes"], rec["sha256"]):
        return None, "image missing or fails its size/SHA-256"
    if job.truth and truths.get(job.truth) is None:
        return None, TRUTH_BAD
    return rec, ""


def verify(out: str | Path) -> tuple[int, list[str]]:
    """Check the library in ``out``: ``library.json`` and every variant's ``scene.json`` against
    the expansion of the spec it stores, the manifest's rows (one per image, its value columns
    the expansion's), every image and truth file against its manifest row, and the geometry
    files against the truth headers' SHA-256. Returns (good images, problems)."""
    out = Path(out)
    info = mf.read_library_info(out)
    if info is None:
        raise LibraryError(f"{out}: holds no library (no library.json, or a damaged one) — give a directory that "
                           "`glsim library SPEC -o DIR` wrote")
    stored = mf.StoredPlan(info)
    lines = _spec_problems(out, info)
    try:
        rows = mf.manifest_rows(out)
    except mf.ManifestError as exc:
        lines.append(str(exc))
        rows = []
    lines += _manifest_problems(out, stored, rows)
    records = {}
    for row in rows:
        with contextlib.suppress(KeyError, ValueError, TypeError):    # (named by _manifest_problems)
            rec = mf.record(row)
            records.setdefault((rec["variant"], rec["camera"], rec["step"]), rec)
    good, problems, _ = check_records(out, stored, records)
    lines += [f"{job.image}: {what}" for job, what in problems]
    seen = set()
    for rec in good.values():
        if not rec.get("truth_file") or rec["truth_file"] in seen:
            continue
        seen.add(rec["truth_file"])
        path = out / rec["truth_file"]
        try:
            t = truthio.read(path)
            t.xi          # decoded: the element map and (ξ, η), not only the header
            geo = truthio.geometry_path(path, t.header["geometry"])
        except GlsimError as exc:
            lines.append(str(exc))
            continue
        if geo.resolve() in seen:
            continue
        seen.add(geo.resolve())
        if not geo.is_file() or sha256_file(geo) != t.header["geometry_sha256"]:
            lines.append(f"{geo}: geometry file missing or fails its SHA-256")
    return len(good), lines


def _spec_problems(out: Path, info: dict) -> list[str]:
    """What in ``library.json`` and the variants' ``scene.json`` files is not the expansion of
    the spec library.json stores (a resume would refuse the directory, or write them again)."""
    from glsim.workflows.library.spec import expand

    where = out / mf.LIBRARY
    try:
        plan = expand(info["spec"], info["base_dir"])
    except (GlsimError, OSError, ValueError) as exc:
        return [f"{where}: its spec does not expand here ({exc}) — a resume would fail the same way; the files "
                "were checked against library.json's own list only"]
    fingerprint = plan.fingerprint()
    if fingerprint != info.get("fingerprint"):
        return [f"{where}: its spec expands to another library than the one it records "
                f"({first_difference(info, plan)}) — a resume refuses the directory: restore library.json, or "
                "render the library again with --force"]
    expected = json.loads(json.dumps(mf.library_info(plan, fingerprint)))
    lines = [f"{where}: its {key} is not the spec's expansion — restore library.json, or run the library command "
             "on the directory (it writes library.json again)"
             for key in sorted(set(expected) | set(info)) if info.get(key) != expected.get(key)][:1]
    for v in plan.variants:
        path = out / v.id / "scene.json"
        try:
            same = path.read_bytes() == v.scene.to_json().encode()
        except OSError as exc:
            lines.append(f"{path}: cannot be read ({exc.strerror or exc}) — run the library command on the "
                         "directory to write it again")
            continue
        if not same:
            lines.append(f"{path}: is not the scene the spec gives variant {v.id} (edited?) — run the library "
                         "command on the directory to write it again")
    return lines


def _manifest_problems(out: Path, plan, rows: list[dict]) -> list[str]:
    """The manifest's columns against the library's, and each row: readable, an image of the
    library, named once, its value columns the variant's parameters (as library.json, which
    :func:`_spec_problems` checks against the spec)."""
    path = out / mf.MANIFEST
    lines = []
    columns = mf.columns(plan.keys)
    if rows and [c for c in rows[0] if c != "_line"] != columns:
        lines.append(f"{path}: its columns are {', '.join(c for c in rows[0] if c != '_line')}, not the library's "
                     f"{', '.join(columns)} — restore it, or delete it and run the library command again")
    images = {(j.variant, j.camera, str(j.step)) for j in plan.jobs}
    first: dict[tuple, int] = {}
    for row in rows:
        line, key = row["_line"], (row.get("variant"), row.get("camera"), row.get("step"))
        if key not in images:
            lines.append(f"{path}: line {line} ({', '.join(map(str, key))}) is not an image of the library")
            continue
        if key in first:
            lines.append(f"{path}: line {line} repeats the row of {key[0]} {key[1]} step {key[2]} (line {first[key]})")
            continue
        first[key] = line
        params = plan.variant(key[0]).params
        for k in plan.keys:
            if row.get(k) != json.dumps(params[k]):
                lines.append(f"{path}: line {line} gives {k} = {row.get(k)} for {key[0]}, whose value is "
                             f"{json.dumps(params[k])} — restore the manifest, or delete it and run the library "
                             "command again")
                break
        else:
            try:
                mf.record(row)
            except (KeyError, ValueError, TypeError) as exc:
                lines.append(f"{path}: line {line} cannot be read ({type(exc).__name__}: {exc})")
    return lines


def print_verify(good: int, problems: list[str], what: str, directory, fix: str) -> int:
    """``--verify``'s lines: up to 20 problems, then the count of good ``what`` and problems (with
    ``fix`` where there are any); exit status 1 with problems, else 0."""
    for p in problems[:20]:
        print(f"bad: {p}")
    if len(problems) > 20:
        print(f"… and {len(problems) - 20} more")
    print(f"glsim library --verify: {good} {what} good, {len(problems)} problems in {directory}/"
          + (f" — {fix}" if problems else ""))
    return 1 if problems else 0
