"""Hostile inputs to what reads a library's files and DIC results: compact truth files (their
checksum, their local coordinates, the geometry they name), .npz members (bounded by their
headers before allocation: geometry files, ``*_truth.npz``, a measured ``.npz``), the library's
``--verify`` (library.json, scene.json and the manifest against the spec's expansion), the
library's arguments (refused before a byte is written) and ``glsim compare``'s inputs. Bombs
run in a subprocess limited to 500 MB of address space."""
import csv
import hashlib
import io
import json
import os
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from _hostile import vouch

from glsim.cli import main as glsim
from glsim.io import geometryfile as G
from glsim.io import npzfile
from glsim.io import truth as T
from glsim.io import truthcodec as C
from glsim.scene import Plate, Render, Scene, Specimen, bulge_scene
from glsim.workflows.library import load_plan, run, verify
from glsim.workflows.library.cli import main as library_main
from glsim.workflows.sequence import write_sequence

BASE = """[[cameras]]
name = "cam0"
size = [64, 48]
fx = 300.0
fy = 300.0
cx = 31.5
cy = 23.5
[specimen.plate]
width = 40.0
height = 30.0
translations = [[0.1, 0.0, 0.0]]
[specimen.pose]
t = [0.0, 0.0, 300.0]
[speckle]
dot_diameter_px = 4.0
[render]
backend = "cpu"
"""
SPEC = 'scene = "base.toml"\nseed = 1\ncameras = ["cam0"]\nsteps = [0, 1]\n[vary]\n"noise.sigma" = [0.5, 1.0]\n'


def write_spec(d: Path, spec: str = SPEC) -> Path:
    (d / "base.toml").write_text(BASE)
    (d / "spec.toml").write_text(spec)
    return d / "spec.toml"


def files(d: Path) -> dict:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A library of 2 variants × 2 steps with truth (CPU backend)."""
    d = tmp_path_factory.mktemp("lib")
    s = run(load_plan(write_spec(d)), d / "lib", workers=1)
    assert s.written == 4 and not s.failed
    return d / "lib"


@pytest.fixture
def lib(library, tmp_path):
    return Path(shutil.copytree(library, tmp_path / "lib", symlinks=True))


def a_truth_file(lib: Path) -> Path:
    return sorted(lib.glob("truth/*.truth"))[0]


def rewrite(path: Path, header=None, blobs=None) -> None:
    """Write the truth file again with header fields and blobs replaced, its checksum made anew
    (what a careful forger does)."""
    t = T.read(path)
    parts = {name: t._blobs[o:o + n] for name, (o, n) in t.header["blobs"].items()}
    parts.update(blobs or {})
    path.write_bytes(C.assemble({k: v for k, v in {**t.header, **(header or {})}.items() if k != "blobs"}, parts))


# ---- crafted .npz bombs: a zip of deflated zeros whose .npy headers declare what they hold ----------

def npy_header(shape, descr="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": tuple(shape)})
    return buf.getvalue()


def deflated(prefix: bytes, zeros: int, chunk: int = 1 << 20) -> tuple[bytes, int, int]:
    """(raw deflate stream, CRC-32, size) of ``prefix`` and ``zeros`` zero bytes, made in chunks
    whose stream repeats after a full flush (a gigabyte in a few MB, in well under a second)."""
    c = zlib.compressobj(1, zlib.DEFLATED, -15)
    head = c.compress(prefix) + c.flush(zlib.Z_FULL_FLUSH)
    block = c.compress(bytes(chunk)) + c.flush(zlib.Z_FULL_FLUSH)
    n, rest = divmod(zeros, chunk)
    crc, z = zlib.crc32(prefix), bytes(chunk)
    for _ in range(n):
        crc = zlib.crc32(z, crc)
    tail = c.compress(bytes(rest)) + c.flush()
    return head + block * n + tail, zlib.crc32(bytes(rest), crc), len(prefix) + zeros


def array_member(shape, descr="<f8"):
    return deflated(npy_header(shape, descr), int(np.prod(shape, dtype=np.int64)) * np.dtype(descr).itemsize)


def zip_of(members: dict) -> bytes:
    """A zip of ``members`` (name → (deflate stream, CRC-32, size)), written by hand."""
    out, central = bytearray(), bytearray()
    for name, (data, crc, size) in members.items():
        n, off = name.encode(), len(out)
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, 0, 0x21, crc, len(data), size, len(n), 0) + n + data
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 8, 0, 0x21, crc, len(data), size, len(n),
                               0, 0, 0, 0, 0, off) + n
    return bytes(out + central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(members), len(members),
                                             len(central), len(out), 0))


def test_the_crafted_zip_is_an_npz_numpy_reads():
    """(The bombs below are real .npz files: the same writer makes a small one numpy loads.)"""
    data = zip_of({"a.npy": array_member((100, 3)), "b.npy": array_member((4,), "<i8")})
    with np.load(io.BytesIO(data)) as z:
        assert z["a"].shape == (100, 3) and not z["a"].any() and z["b"].dtype == np.int64
    got = npzfile.read_npz(data, ["a", "b"])
    assert got["a"].shape == (100, 3) and got["b"].tolist() == [0, 0, 0, 0]


# ---- compact truth ------------------------------------------------------------------------------------

def test_a_changed_byte_anywhere_is_refused_by_name(lib):
    path = a_truth_file(lib)
    data = path.read_bytes()
    (n,) = struct.unpack("<Q", data[C.PREFIX - 8:C.PREFIX])
    for at in (8, 39, C.PREFIX - 1, C.PREFIX + n // 2, C.PREFIX + n + 3, len(data) - 1):   # digest, length, header, blobs
        b = bytearray(data)
        b[at] ^= 0x10
        path.write_bytes(bytes(b))
        with pytest.raises(T.TruthFileError, match=r"\.truth: .*(checksum|damaged|truncated).*re-render"):
            T.read(path).maps()
    path.write_bytes(data + b"\0")
    with pytest.raises(T.TruthFileError, match=r"damaged \(\d+ data bytes where its header gives \d+\)"):
        T.read(path)


def test_local_coordinates_out_of_range_are_refused_when_written_and_when_read(lib):
    el = np.array([[-1, 0, 0], [1, 1, -1]])
    ok = np.full((2, 3), 0.5)
    for bad in (3.0, np.nan, np.inf, 3.4e306):
        xi = ok.copy()
        xi[1, 1] = bad
        with pytest.raises(C.TruthFileError, match=r"ξ at pixel \(1, 1\) of element 1 is .*outside the element's local "
                                                   r"coordinates \[−1, 1\] widened to ±2"):
            C.encode(el, xi, ok, {})
    C.encode(el, np.where(el >= 0, 2.0, np.nan), np.full((2, 3), -2.0), {})     # the bound itself is written
    # a forged file, its checksum made anew: ξ of 3.4e306 is refused on load (the old reader returned it)
    path = a_truth_file(lib)
    t = T.read(path)
    idx, same1, same2 = C._runs(t.element)
    xi = t.xi.ravel()[idx].copy()
    xi[len(xi) // 2] = 3.4e306
    codes = np.concatenate([C.encode_local(xi, same1, same2), C.encode_local(t.eta.ravel()[idx], same1, same2)])
    rewrite(path, blobs={"local": C._zstd().ZstdCompressor(level=3).compress(C._shuffle(codes))})
    with pytest.raises(T.TruthFileError, match=r"its ξ at pixel \(\d+, \d+\) is 3\.4e\+306, outside the element's "
                                               r"local coordinates .*--verify"):
        T.read(path).xi


@pytest.mark.parametrize("rel", ["/etc/passwd", "../../outside.npz", "../geometry/../../outside.npz",
                                 "../truth/../../outside.npz", "sub/../../outside.npz", "", "..\\outside.npz",
                                 "../geometry"])
def test_the_header_geometry_path_stays_in_the_library(lib, rel):
    (lib.parent / "outside.npz").write_bytes((next(lib.glob("geometry/*.npz"))).read_bytes())
    path = a_truth_file(lib)
    rewrite(path, {"geometry": rel})
    with pytest.raises(T.TruthFileError, match="outside the library \\(not followed\\)"):
        T.read(path).maps()
    vouch(lib)
    _, problems = verify(lib)
    assert any("outside the library (not followed)" in p for p in problems), problems


def test_a_geometry_folder_linked_out_of_the_library_is_not_followed(lib, tmp_path):
    outside = tmp_path / "elsewhere"
    shutil.move(lib / "geometry", outside)
    os.symlink(outside, lib / "geometry")
    with pytest.raises(T.TruthFileError, match="outside the library \\(not followed\\)"):
        T.read(a_truth_file(lib)).maps()
    assert T.read(a_truth_file(lib), G.read_geometry(next(outside.glob("*.npz")))).xi is not None  # (given: used)


def test_the_geometry_sha256_is_checked_before_the_geometry_is_parsed(lib, monkeypatch):
    geo = next(lib.glob("geometry/*.npz"))
    g = G.read_geometry(geo)
    arrays = G.geometry_arrays(g.nodes, g.quads, {s: g.displacements[i] + 0.01 for i, s in enumerate(g.steps)},
                               g.element_labels)
    geo.write_bytes(G.geometry_bytes(arrays))       # a sound geometry file, not the one the truth was made with
    parsed = []
    monkeypatch.setattr(npzfile, "read_npz", lambda *a, **k: parsed.append(1))
    with pytest.raises(T.TruthFileError, match="fails the SHA-256 its truth file's header gives"):
        T.read(a_truth_file(lib)).maps()
    assert not parsed


def test_npz_members_are_bounded_by_their_headers_before_allocation():
    bomb = zip_of({"a.npy": array_member((50_000_000, 3))})             # 1.2 GB in 5 MB
    with pytest.raises(npzfile.NpzError, match=r"its arrays declare 1\.12 GiB \(a: float64 \(50000000, 3\)\), more "
                                               r"than the 0\.0977 GiB this process may use"):
        npzfile.read_npz(bomb, ["a"], budget=100 << 20)
    small = array_member((10, 3))
    lying = (small[0], small[1], small[2] + 8)                          # the zip's size is not the header's
    with pytest.raises(npzfile.NpzError, match=r"a is 376 bytes in the zip where its header declares float64 "
                                               r"\(10, 3\) \(368 bytes\)"):
        npzfile.read_npz(zip_of({"a.npy": lying}), ["a"])
    with pytest.raises(npzfile.NpzError, match="a holds Python objects"):
        npzfile.read_npz(zip_of({"a.npy": deflated(npy_header((2,), "|O"), 0)}), ["a"])
    with pytest.raises(npzfile.NpzError, match=r"has no b \(it holds a\)"):
        npzfile.read_npz(zip_of({"a.npy": small}), ["a", "b"])
    with pytest.raises(npzfile.NpzError, match="not a readable .npz"):
        npzfile.read_npz(b"PK\3\4 not a zip at all", ["a"])


BOMBS = """
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (500 << 20, 500 << 20))
import contextlib, io
from glsim.cli import main
from glsim.errors import GlsimError
from glsim.io import truth as T
out = []
for kind, arg in json.loads(sys.argv[1]):
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            if kind == "truth":
                T.load(arg).maps()
                out.append("loaded")
            else:
                out.append([main(arg), err.getvalue()])
    except GlsimError as exc:
        out.append(str(exc))
    except BaseException as exc:
        out.append(repr(exc))
print(json.dumps(out))
"""


@pytest.mark.process
def test_npz_bombs_are_refused_by_their_headers_under_a_500_MB_address_space_limit(lib, tmp_path):
    # a geometry bomb its (forged, checksummed) truth file vouches for
    nodes = array_member((50_000_000, 3))
    small = {"quads.npy": array_member((1, 4), "<i8"), "steps.npy": array_member((1,), "<i8"),
             "displacements.npy": array_member((1, 50_000_000, 3)), "element_labels.npy": array_member((1,), "<i8")}
    bomb = zip_of({"nodes.npy": nodes, **small})
    (lib / "geometry" / "bomb.npz").write_bytes(bomb)
    truth = a_truth_file(lib)
    rewrite(truth, {"geometry": "../geometry/bomb.npz", "geometry_sha256": hashlib.sha256(bomb).hexdigest()})
    # a *_truth.npz of glsim render --truth, and a measured .npz for glsim compare
    maps = {f"{k}.npy": array_member((2, 2), "|b1" if k == "mask" else "<f8") for k in T.Truth.FIELDS}
    maps["xi.npy"] = array_member((8192, 8192))
    (tmp_path / "c_0000_truth.npz").write_bytes(zip_of(maps))
    (tmp_path / "measured.npz").write_bytes(zip_of({"ss_x.npy": array_member((100_000_000,)),
                                                   "ss_y.npy": array_member((3,)), "valid.npy": array_member((1, 3))}))
    cases = [["truth", str(truth)], ["truth", str(tmp_path / "c_0000_truth.npz")],
             ["cli", ["compare", str(tmp_path / "measured.npz"), "--truth", str(tmp_path), "--step", "1", "-o", str(tmp_path / "o")]]]
    r = subprocess.run([sys.executable, "-c", BOMBS, json.dumps(cases)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    geometry, maps_npz, measured = json.loads(r.stdout)
    assert "bomb.npz: its arrays declare 2.24 GiB (nodes: float64 (50000000, 3))" in geometry, geometry
    assert "c_0000_truth.npz: its arrays declare 0.5 GiB (xi: float64 (8192, 8192))" in maps_npz, maps_npz
    assert measured[0] == 2 and "measured.npz: its arrays declare 0.745 GiB (ss_x" in measured[1], measured
    for text in (geometry, maps_npz, measured[1]):
        assert "GiB this process may use" in text and "Traceback" not in text
    assert not (tmp_path / "o").exists()


# ---- glsim library: --verify, arguments, the manifest ---------------------------------------------------

def _verify(lib: Path, capsys) -> str:
    assert library_main([str(lib), "--verify"]) == 1
    out = capsys.readouterr().out
    assert "Traceback" not in out
    return out


def _edit_manifest(lib: Path, edit) -> None:
    with open(lib / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    rows = edit(rows)
    with open(lib / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def test_a_sound_library_verifies(library, capsys):
    assert library_main([str(library), "--verify"]) == 0
    assert "4 images good, 0 problems" in capsys.readouterr().out


def test_verify_names_an_edited_scene_json(lib, capsys):
    scene = json.loads((lib / "v0001" / "scene.json").read_text())
    scene["noise"]["sigma"] = 7.0
    (lib / "v0001" / "scene.json").write_text(json.dumps(scene))
    out = _verify(lib, capsys)
    assert "v0001/scene.json: is not the scene the spec gives variant v0001 (edited?)" in out
    assert "1 problems" in out


def test_verify_names_an_edited_manifest_value_column(lib, capsys):
    _edit_manifest(lib, lambda rows: [{**r, "noise.sigma": "9.0"} if r["variant"] == "v0000" else r for r in rows])
    out = _verify(lib, capsys)
    assert "manifest.csv: line 2 gives noise.sigma = 9.0 for v0000, whose value is 0.5" in out


def test_verify_names_a_repeated_manifest_row(lib, capsys):
    _edit_manifest(lib, lambda rows: rows + [rows[1]])
    out = _verify(lib, capsys)
    assert "manifest.csv: line 6 repeats the row of v0000 cam0 step 1 (line 3)" in out


def test_verify_names_a_manifest_row_of_no_image(lib, capsys):
    _edit_manifest(lib, lambda rows: rows + [{**rows[0], "variant": "v0007"}])
    assert "manifest.csv: line 6 (v0007, cam0, 0) is not an image of the library" in _verify(lib, capsys)


def test_verify_names_an_edited_library_json_spec_and_field(lib, capsys):
    info = json.loads((lib / "library.json").read_text())
    good = json.loads(json.dumps(info))
    info["spec"]["vary"]["noise.sigma"] = [0.5, 3.0]
    (lib / "library.json").write_text(json.dumps(info))
    out = _verify(lib, capsys)
    assert ("library.json: its spec expands to another library than the one it records (variant v0001 has "
            '{"noise.sigma": 1.0} there, {"noise.sigma": 3.0} now)') in out
    (lib / "library.json").write_text(json.dumps({**good, "seed": 99}))
    assert "library.json: its seed is not the spec's expansion" in _verify(lib, capsys)
    (lib / "library.json").write_text(json.dumps({**good, "spec": {**good["spec"], "scene": "gone.toml"}}))
    assert "library.json: its spec does not expand here (" in _verify(lib, capsys)


def test_resume_after_verify_is_clean(library, tmp_path, capsys):
    """A library whose [vary] keys are not in alphabetical order: library.json keeps their order,
    so the stored spec expands to the same library (verify clean, resume keeps everything)."""
    d = tmp_path / "unsorted"
    d.mkdir()
    s = write_spec(d, SPEC.replace("steps = [0, 1]", "steps = [0]").replace("[0.5, 1.0]", "[0.5]")
                   + '"speckle.seed" = [3]\n"lighting.ambient" = [0.0]\n')
    run(load_plan(s), d / "lib", workers=1)
    assert library_main([str(d / "lib"), "--verify"]) == 0
    assert library_main([str(d / "lib"), "--workers", "1", "-q"]) == 0
    assert "0 images written, 1 kept" in capsys.readouterr().out


@pytest.mark.parametrize("workers", ["0", "-1"])
def test_workers_below_one_are_refused_before_anything_is_written(tmp_path, capsys, workers):
    s = write_spec(tmp_path)
    before = files(tmp_path)
    assert library_main([str(s), "-o", str(tmp_path / "out"), "--workers", workers, "-q"]) == 2
    assert f"--workers {workers}: must be ≥ 1" in capsys.readouterr().err
    with pytest.raises(Exception, match=f"--workers {workers}: must be ≥ 1"):
        run(load_plan(s), tmp_path / "out", workers=int(workers))
    assert files(tmp_path) == before and not (tmp_path / "out").exists()


@pytest.mark.parametrize("image", [b"not an image", None])
def test_a_bad_reference_image_is_refused_before_the_library_directory_is_made(tmp_path, capsys, image):
    s = write_spec(tmp_path)
    (tmp_path / "base.toml").write_text(BASE.replace("dot_diameter_px = 4.0", 'image = "ref.png"\nmm_per_px = 0.05'))
    if image is not None:
        (tmp_path / "ref.png").write_bytes(image)
    before = files(tmp_path)
    assert library_main([str(s), "-o", str(tmp_path / "out"), "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert "variant v0000" in err and "speckle.image" in err and "ref.png" in err and "Traceback" not in err
    assert files(tmp_path) == before and not (tmp_path / "out").exists()


@pytest.mark.parametrize("damage", [b"\xff\xfe latin \xe9", b'"' + b"x" * (130 << 10) + b'"'])
def test_a_damaged_manifest_is_named_in_resume_and_verify(lib, capsys, damage):
    data = (lib / "manifest.csv").read_bytes()
    (lib / "manifest.csv").write_bytes(data + damage + b"\n")
    before = files(lib)
    assert library_main([str(lib), "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    culprit = "is not UTF-8 text (byte 0xff at offset" if damage[0] == 0xFF else "line 6 is not CSV (field larger"
    assert "manifest.csv: " + culprit in err and "Traceback" not in err, err
    assert files(lib) == before
    assert culprit in _verify(lib, capsys)


# ---- glsim compare ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    cam = bulge_scene(size=(96, 72)).cameras[0]
    scene = Scene(cameras=(cam,), render=Render(backend="cpu"),
                  specimen=Specimen(plate=Plate(width=80, height=60, nx=3, ny=2, translations=((0.3, -0.2, 0.1),)),
                                    t=(0.0, 0.0, 600.0)))
    write_sequence(scene, out)
    return out


ROWS = "u,v,U,V,W,valid\n40,30,0.3,-0.2,0.1,1\n50,36,0.3,-0.2,0.1,1\n"


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_compare_refuses_a_valid_point_that_is_not_a_number(rendered, tmp_path, capsys, bad):
    (tmp_path / "dic.csv").write_text(ROWS + f"45,33,{bad},-0.2,0.1,1\n")
    assert glsim(["compare", str(tmp_path / "dic.csv"), "--truth", str(rendered), "--step", "1"]) == 2
    err = capsys.readouterr().err
    assert f"dic.csv: data row 3 has U/V/W = {bad}, -0.2, 0.1, not finite numbers" in err and "Traceback" not in err
    assert not (tmp_path / "compare").exists()
    (tmp_path / "dic.csv").write_text(ROWS + f"45,33,{bad},-0.2,0.1,0\n")      # marked invalid: left out
    assert glsim(["compare", str(tmp_path / "dic.csv"), "--truth", str(rendered), "--step", "1"]) == 0
    res = json.loads((tmp_path / "compare" / "compare.json").read_text())
    assert res["n_compared"] == 2 and all(np.isfinite(r["mean_mm"]) for r in res["rows"])
    (tmp_path / "dic.csv").write_text(ROWS + f"{bad},33,0.3,-0.2,0.1,0\n")      # u, v always finite
    assert glsim(["compare", str(tmp_path / "dic.csv"), "--truth", str(rendered), "--step", "1"]) == 2
    assert f"data row 3 has u, v = {bad}, 33, not finite numbers" in capsys.readouterr().err


@pytest.mark.parametrize("case", ["latin-1", "128 KB field", "-o a file", "npz shapes", "npz NaN"])
def test_compare_names_bad_files_and_output(rendered, tmp_path, capsys, case):
    result, out = tmp_path / "dic.csv", []
    result.write_text(ROWS)
    if case == "latin-1":
        result.write_bytes("u;v;U;V;W\n40;30;0,3;0;0 # déjà\n".encode("latin-1"))
        culprit = "dic.csv: is not UTF-8 text (byte 0xe9 at offset 27) — save the DIC result as UTF-8"
    elif case == "128 KB field":
        result.write_text(ROWS + "45,33,0.3," + '"' + "1" * ((128 << 10) + 1) + '"' + ",0.1,1\n")
        culprit = "dic.csv: line 4 of its non-blank lines is not CSV (field larger than field limit"
    elif case == "-o a file":
        (tmp_path / "taken").write_text("mine")
        out = ["-o", str(tmp_path / "taken")]
        culprit = "taken: is a file, not a directory — give a directory for compare.json"
    else:
        result = tmp_path / "measured.npz"
        arrays = {"ss_x": np.array([40.0, 50.0]), "ss_y": np.array([30.0, 36.0]), "valid": np.ones((1, 2), bool),
                  "U": np.tile([0.3, -0.2, 0.1], (1, 2, 1))}
        if case == "npz shapes":
            arrays["U"] = arrays["U"][:, :1]
            culprit = "measured.npz: U is float64 (1, 1, 3), not numbers of shape (1, 2, 3)"
        else:
            arrays["U"][0, 1, 2] = np.nan
            culprit = "measured.npz: point 1 has U/V/W = 0.3, -0.2, nan, not finite numbers"
        np.savez(result, **arrays)
    before = files(tmp_path)
    assert glsim(["compare", str(result), "--truth", str(rendered), "--step", "1", *out]) == 2
    err = capsys.readouterr().err
    assert culprit in err and "Traceback" not in err, err
    assert files(tmp_path) == before


def test_compare_reads_a_sound_measured_npz(rendered, tmp_path, capsys):
    arrays = {"ss_x": np.array([40.0, 50.0]), "ss_y": np.array([30.0, 36.0]), "valid": np.array([[1, 1], [1, 0]], bool),
              "U": np.array([[[0, 0, 0], [0, 0, 0]], [[0.3, -0.2, 0.1], [np.nan] * 3]])}
    np.savez(tmp_path / "measured.npz", **arrays)
    assert glsim(["compare", str(tmp_path / "measured.npz"), "--truth", str(rendered), "--step", "1"]) == 0
    res = json.loads((tmp_path / "compare" / "compare.json").read_text())
    assert res["n_compared"] == 1
    assert {r["dir"]: r["max_abs_mm"] for r in res["rows"]} == pytest.approx({"U": 0, "V": 0, "W": 0}, abs=1e-9)
