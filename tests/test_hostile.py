"""Hostile and broken inputs: each is refused with a named glsim error — the key or file, the
culprit and the fix — before anything large is allocated, quickly, writing nothing (no
MemoryError, GL error, SystemExit or traceback). Files are crafted here by writing bytes: image
headers, compact truth files, Exodus II copies. The cases whose naive handling allocates
gigabytes run again in one subprocess limited to 500 MB of address space. Last, a small
property-based fuzz of the scene and spec loaders: only glsim's own errors may come out."""
import json
import os
import shutil
import struct
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from _hostile import files, main_under_cap, tiff, vouch, write

from glsim.cli import main
from glsim.errors import GlsimError, RenderWarning
from glsim.io import truth as T
from glsim.io import truthcodec as C
from glsim.scene import load_scene
from glsim.io.fe import specimen_mesh
from glsim.imaging.reference import make_reference
from glsim.workflows.library import load_plan, run, verify
from glsim.workflows.library.cli import main as library_main

ROOT = Path(__file__).resolve().parents[1]
SECONDS = 2.0          # a refusal takes well under this in a started process

CAMERA = '[[cameras]]\nname = "cam0"\nsize = [{W}, {H}]\nfx = 300.0\nfy = 300.0\ncx = 31.5\ncy = 23.5\n'
PLATE = "[specimen.plate]\nwidth = 40.0\nheight = 30.0\n{extra}translations = [[0.1, 0.0, 0.0]]\n" \
        "[specimen.pose]\nt = [0.0, 0.0, 300.0]\n"


def scene_text(size=(64, 48), specimen=PLATE.format(extra=""), speckle="dot_diameter_px = 4.0\n",
               render='backend = "cpu"\n') -> str:
    return CAMERA.format(W=size[0], H=size[1]) + specimen + "[speckle]\n" + speckle + "[render]\n" + render


# ---- crafted files -----------------------------------------------------------------------------------

def huge_tiff(path: Path, side: int = 30000) -> Path:
    """A 4 × 4 TIFF whose ImageWidth and ImageLength tags say ``side``."""
    return tiff(path, np.zeros((4, 4), np.uint8), side)


def huge_png(path: Path, side: int = 30000) -> Path:
    """A 4 × 4 PNG whose IHDR says ``side`` × ``side`` (its CRC made right)."""
    import imageio.v3 as iio
    iio.imwrite(path, np.zeros((4, 4), np.uint8), extension=".png")
    b = bytearray(path.read_bytes())
    struct.pack_into(">II", b, 16, side, side)
    struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    return write(path, bytes(b))


def exodus_scene(d: Path, damage) -> Path:
    """examples/exodus with plate_out.e damaged by ``damage(bytes) -> bytes``; its scene file."""
    write(d / "plate_out.e", damage((ROOT / "examples/exodus/plate_out.e").read_bytes()))
    return Path(shutil.copy(ROOT / "examples/exodus/scene.toml", d / "scene.toml"))


def mesh_scene(d: Path, name: str, content: bytes | None, extra: str = "") -> Path:
    """A scene whose specimen is the mesh file ``name`` (``content``; None: a directory)."""
    (d / name).mkdir(parents=True) if content is None else write(d / name, content)
    specimen = f'[specimen.mesh]\npath = "{name}"\n{extra}[specimen.pose]\nt = [0.0, 0.0, 300.0]\n'
    return write(d / "scene.toml", scene_text(specimen=specimen))


def vtu(path: Path) -> bytes:
    """The bytes of a one-quad .vtu (written at ``path``)."""
    import meshio
    meshio.Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]), [("quad", np.array([[0, 1, 2, 3]]))]).write(path)
    return path.read_bytes()


def fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path


def spec(d: Path, body: str, steps: str = "[0]") -> Path:
    write(d / "base.toml", scene_text())
    return write(d / "spec.toml", f'scene = "base.toml"\nseed = 1\ncameras = ["cam0"]\nsteps = {steps}\n' + body)


LATIN1_CSV = "label;ux;uy;uz\n101;0;0;0 # déjà\n".encode("latin-1")


# ---- each case: d → (argv, the culprit the message names) -------------------------------------------

def _render(scene: Path, *extra) -> list:
    return ["render", str(scene), "-o", str(scene.parent / "out"), "-q", *extra]


def _library(spec_file: Path, *extra) -> list:
    return ["library", str(spec_file), "-o", str(spec_file.parent / "out"), "-q", *extra]


CASES = {
    # limits checked before the work
    "steps 0-1e9": lambda d: (_render(write(d / "s.toml", scene_text()), "--steps", "0-1000000000"),
                              "--steps: gives 1,000,000,001 load steps, more than glsim's limit of 10,000"),
    "bulge steps 1e6": lambda d: (_render(write(d / "s.toml", scene_text(specimen="[specimen.bulge]\nsteps = 1000000\n"))),
                                  "specimen.bulge.steps: gives 1,000,000 load steps"),
    "plate 1e5 × 1e5": lambda d: (_render(write(d / "s.toml", scene_text(specimen=PLATE.format(
        extra="nx = 100000\nny = 100000\n")))), "specimen.plate.nx: gives 10,000,000,000 elements"),
    "dot 1e6": lambda d: (_render(write(d / "s.toml", scene_text(speckle="dot_diameter_px = 1e6\n"))),
                          "speckle.dot_diameter_px: 1e+06 px is larger than camera cam0's image"),
    "dot 3000": lambda d: (_render(write(d / "s.toml", scene_text(speckle="dot_diameter_px = 3000.0\n"))),
                           "speckle.dot_diameter_px: 3000 px is larger than camera cam0's image"),
    "camera 100000²": lambda d: (_render(write(d / "s.toml", scene_text(size=(100000, 100000)))),
                                 "cameras[0].size: the image is 100000 × 100000 px; the limit is 16384 px a side"),
    "camera 16385 wide": lambda d: (_render(write(d / "s.toml", scene_text(size=(16385, 48)))),
                                    "cameras[0].size: the image is 16385 × 48 px"),
    "1024 samples per pixel": lambda d: (_render(write(d / "s.toml", scene_text(render="samples_per_pixel = 1024\n"))),
                                         "render.samples_per_pixel: gives 1,024 samples per pixel"),
    "GL target 24576 px wide": lambda d: (_render(write(d / "s.toml", scene_text(size=(8192, 48),
                                                                                render="samples_per_pixel = 9\n"))),
                                          "render.samples_per_pixel: a 8192 × 48 px image at 9 samples per pixel "
                                          "needs a 24576 × 144 px GL render target"),
    "library range 1e10": lambda d: (_library(spec(d, '[vary]\n"speckle.seed" = {range = [0, 10000000000]}\n')),
                                     "vary.speckle.seed.range: gives 10,000,000,000 values"),
    "library grid 1e4 × 1e4": lambda d: (_library(spec(d, '[vary]\n"speckle.seed" = {range = [0, 10000]}\n'
                                                          '"noise.sigma" = {linspace = [0, 2, 10000]}\n')),
                                         "vary: gives 100,000,000 variants"),
    "library linspace n 1e10": lambda d: (_library(spec(d, '[vary]\n"noise.sigma" = {linspace = [0, 2, 10000000000]}\n')),
                                          "vary.noise.sigma.linspace: gives 10,000,000,000 values"),
    "library draw n 1e10": lambda d: (_library(spec(d, '[vary]\n"noise.sigma" = {uniform = [0, 2], n = 10000000000}\n')),
                                      "vary.noise.sigma.n: gives 10,000,000,000 values"),
    "library random n 1e10": lambda d: (_library(spec(d, 'mode = "random"\nn = 10000000000\n[vary]\n'
                                                         '"noise.sigma" = {uniform = [0, 2]}\n')),
                                        "n: gives 10,000,000,000 variants"),
    "library steps 0-1e9": lambda d: (_library(spec(d, "", steps='"0-1000000000"')),
                                      "steps: gives 1,000,000,001 load steps"),
    # headers trusted without limits
    "TIFF header 30000²": lambda d: (_render(write(d / "s.toml", scene_text(
        speckle=f'image = "{huge_tiff(d / "ref.tif")}"\nmm_per_px = 0.05\n'))),
        "ref.tif (as its header declares) is 30000 × 30000 px"),
    "PNG header 30000²": lambda d: (_render(write(d / "s.toml", scene_text(
        speckle=f'image = "{huge_png(d / "ref.png")}"\nmm_per_px = 0.05\n'))),
        "ref.png (as its header declares) is 30000 × 30000 px"),
    "Exodus record count 2e9": lambda d: (_render(exodus_scene(d, lambda b: b[:4] + struct.pack(">i", 2_000_000_000) + b[8:])),
                                          "plate_out.e: stored step 11 of the 2,000,000,000 its header declares lies "
                                          "beyond the end of the file"),
    "Exodus truncated by 1.5 KB": lambda d: (_render(exodus_scene(d, lambda b: b[:-1536])),
                                             "plate_out.e: stored step 10 of the 11 its header declares lies beyond"),
    # tracebacks instead of messages
    "garbage .vtu": lambda d: (_render(mesh_scene(d, "m.vtu", b"<?xml version='1.0'?>\n<VTKFile type='Unstr")),
                               "m.vtu: meshio could not read it"),
    "truncated .vtu": lambda d: (_render(mesh_scene(d, "m.vtu", vtu(d / "m.vtu")[:300])), "m.vtu: meshio could not read it"),
    "empty .inp": lambda d: (_render(mesh_scene(d, "m.inp", b"")), "m.inp: holds no nodes"),
    "latin-1 CSV": lambda d: (_render(mesh_scene(d, "plate.inp", (ROOT / "examples/plate_inp/plate.inp").read_bytes(),
                                                 f'csv = ["{write(d / "u1.csv", LATIN1_CSV)}"]\n')),
                              "u1.csv: is not UTF-8 text (it holds the byte 0xe9"),
    "TOML nested 500 deep": lambda d: (_render(write(d / "s.toml", scene_text() + "x = " + "[" * 500 + "]" * 500 + "\n")),
                                       "s.toml: nests tables or lists more than 64 deep"),
    "JSON nested 500 deep": lambda d: (_render(write(d / "scene.json", "[" * 500 + "]" * 500)),
                                       "scene.json: nests tables or lists more than 64 deep"),
    "spec nested 500 deep": lambda d: (_library(write(d / "spec.toml", "x = " + "{a = " * 500 + "1" + "}" * 500)),
                                       "spec.toml: nests tables or lists more than 64 deep"),
    "FIFO as scene": lambda d: (_render(fifo(d / "s.toml")), "s.toml: is a FIFO (named pipe), not a file"),
    "directory as mesh": lambda d: (_render(mesh_scene(d, "m.inp", None)), "m.inp is a directory, not a file"),
    "/dev/zero as image": lambda d: (_render(write(d / "s.toml", scene_text(speckle='image = "/dev/zero"\nmm_per_px = 0.05\n'))),
                                     "speckle.image: /dev/zero is a character device, not a file"),
}
# naively, these allocate gigabytes (or wait forever): run again under a 500 MB address-space limit
HEAVY = ("steps 0-1e9", "bulge steps 1e6", "plate 1e5 × 1e5", "dot 1e6", "camera 100000²", "library range 1e10",
         "library grid 1e4 × 1e4", "library linspace n 1e10", "library draw n 1e10", "library random n 1e10",
         "library steps 0-1e9", "TIFF header 30000²", "Exodus record count 2e9", "/dev/zero as image")


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_input_is_refused_by_name_quickly_writing_nothing(tmp_path, capsys, case):
    d = tmp_path / "in"
    d.mkdir()
    argv, culprit = CASES[case](d)
    before = files(d)
    t0 = time.perf_counter()
    assert main(argv) == 2
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert culprit in err, err
    assert "Traceback" not in err and " — " in err          # the fix follows the problem
    assert seconds < SECONDS, f"{case}: refused after {seconds:.2f} s"
    assert files(d) == before and not (d / "out").exists()


@pytest.mark.process
def test_the_heavy_cases_are_refused_under_a_500_MB_address_space_limit(tmp_path):
    cases = {}
    for i, case in enumerate(HEAVY):
        d = tmp_path / f"c{i}"
        d.mkdir()
        cases[case] = CASES[case](d)
    results = main_under_cap([argv for argv, _ in cases.values()], timeout=120)
    for (case, (_, culprit)), (rc, err) in zip(cases.items(), results):
        assert rc == 2 and culprit in err, (case, rc, err)


def test_a_dry_run_of_a_million_variants_prints_the_count_first_in_seconds(tmp_path, capsys):
    s = spec(tmp_path, '[vary]\n"speckle.seed" = {range = [0, 1000]}\n"noise.sigma" = {linspace = [0, 2, 1000]}\n')
    t0 = time.perf_counter()
    assert library_main([str(s), "--dry-run"]) == 0
    assert time.perf_counter() - t0 < 10
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("1000000 variants, about 1000000 images")
    assert lines[1].split() == ["variant", "speckle.seed", "noise.sigma", "images"]
    assert lines[-3].startswith("v999999 ") and "nothing was written" in lines[-1]
    assert not (tmp_path / "spec").exists()


# ---- the speckle dot ------------------------------------------------------------------------------------

def test_a_dot_too_large_to_be_seen_is_warned_of_one_larger_than_the_reference_refused(tmp_path):
    """The plate spans 40 × 30 camera px (77 reference px high with its margin)."""
    scene = load_scene(write(tmp_path / "s.toml", scene_text(size=(320, 240), speckle="dot_diameter_px = 20.0\n")))
    with pytest.warns(RenderWarning, match=r"speckle.dot_diameter_px = 20 px: only 1.9 dots fit across the specimen, "
                                           "so the pattern cannot be seen"):
        make_reference(scene, specimen_mesh(scene))
    big = load_scene(write(tmp_path / "b.toml", scene_text(size=(320, 240), speckle="dot_diameter_px = 45.0\n")))
    with pytest.raises(GlsimError, match=r"speckle.dot_diameter_px: 45 px makes dots of 90 reference px, larger "
                                         r"than the reference image \(97 × 77 px\)"):
        make_reference(big, specimen_mesh(big))


# ---- compact truth and library files ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A one-image library with truth (CPU backend)."""
    d = tmp_path_factory.mktemp("lib")
    s = spec(d, "")
    run(load_plan(s), d / "lib", workers=1)
    return d / "lib"


def rewrite_truth(path: Path, header=None, blobs=None) -> None:
    """Write ``path`` again with header fields and blobs replaced (offsets recomputed)."""
    t = T.read(path)
    parts = {name: t._blobs[o:o + n] for name, (o, n) in t.header["blobs"].items()}
    parts.update(blobs or {})
    head = {**t.header, **(header or {})}
    head["blobs"], pos = {}, 0
    for name, b in parts.items():
        head["blobs"][name] = [pos, len(b)]
        pos += len(b)
    text = json.dumps(head).encode()
    path.write_bytes(C.container(text, b"".join(parts.values())))


def zstd_frame_declaring(size: int) -> bytes:
    """A zstd frame whose header declares ``size`` bytes of content (single segment, 8-byte
    Frame_Content_Size) with one 16-byte RLE block: a decoder that trusts it allocates ``size``."""
    block = (1 | 1 << 1 | 16 << 3).to_bytes(3, "little") + b"\0"        # last block, RLE, 16 bytes
    return struct.pack("<IB", 0xFD2FB528, 0xE0) + struct.pack("<Q", size) + block


TRUTH_DAMAGE = {
    "header 32768²": ({"size": [32768, 32768]}, {}, "size: the image is 32768 × 32768 px; the limit is 16384 px"),
    "zstd frame of 4 GiB": ({}, {"element": zstd_frame_declaring(4 << 30)},
                            "blob 'element' holds 4294967296 bytes where the header's size gives"),
    "no geometry": ({"geometry": None}, {}, "its header's geometry is None; the file is damaged"),
    "blobs a string": ({"blobs": "x"}, None, "its header's blobs is 'x'"),
    "geometry outside": ({"geometry": "../../../../outside.npz"}, {}, "outside the library (not followed)"),
}


@pytest.mark.parametrize("case", list(TRUTH_DAMAGE))
def test_verify_decodes_truth_files_and_names_a_damaged_one(library, tmp_path, case):
    header, blobs, culprit = TRUTH_DAMAGE[case]
    lib = Path(shutil.copytree(library, tmp_path / "lib"))
    path = next(lib.rglob("*.truth"))
    if blobs is None:         # a header that is not even a table of blobs: write it by hand
        text = json.dumps({**T.read(path).header, **header}).encode()
        path.write_bytes(C.container(text, b""))
    else:
        rewrite_truth(path, header, blobs)
    vouch(lib)
    t0 = time.perf_counter()
    good, problems = verify(lib)
    assert time.perf_counter() - t0 < SECONDS
    assert len(problems) == 1 and culprit in problems[0], problems
    if case != "geometry outside":
        with pytest.raises(T.TruthFileError, match=culprit.replace("(", r"\(").replace(")", r"\)")):
            T.read(path).xi


@pytest.mark.parametrize("damage", [lambda info: info.pop("jobs"), lambda info: info.update(variants=[1, 2]),
                                    lambda info: info["jobs"][0].__setitem__(3, "../../escape.tif"),
                                    lambda info: info.update(spec="x")])
def test_a_damaged_library_json_is_named_in_verify_and_resume(library, tmp_path, capsys, damage):
    lib = Path(shutil.copytree(library, tmp_path / "lib"))
    info = json.loads((lib / "library.json").read_text())
    damage(info)
    (lib / "library.json").write_text(json.dumps(info))
    before = files(lib)
    for argv in ([str(lib), "--verify"], [str(lib)]):
        assert library_main(argv) == 2
        err = capsys.readouterr().err
        assert "holds no library (no library.json, or a damaged one)" in err and "Traceback" not in err
    assert files(lib) == before
