"""Hostile scene values, meshes, [vary] draws and rig files: each is refused by a named glsim error at
its root — the key, the culprit and the fix — with exit status 2 and nothing written, where a
traceback (LinAlgError, ZeroDivisionError, IndexError, OverflowError, cv2's SystemError) or a message
blaming another key (the internal reference camera's fx, speckle.oversample) came before. The
scene cases are refused before either backend renders, so the CPU and GL backends refuse alike:
the CPU one always runs, the GL comparison is marked ``gl``; the CLI in a separate process, under a
500 MB address-space limit, is marked ``slow``."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _hostile import files, write

from glsim.cli import main
from glsim.errors import SceneError
from glsim.limits import MAX_COORDINATE_MM, MAX_DISTORTION, MAX_FOCAL_PX
from glsim.scene import load_scene
from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh
from glsim.imaging.reference import surface_normal

CAMERA = ('[[cameras]]\nname = "{name}"\nsize = [64, 48]\nfx = {fx}\nfy = 300.0\ncx = 31.5\ncy = 23.5\n{extra}')
PLATE = "[specimen.plate]\nwidth = 40.0\nheight = 30.0\ntranslations = [{tr}]\n[specimen.pose]\nt = {t}\n"
MESH = '[specimen.mesh]\npath = "m.inp"\n{extra}[specimen.pose]\nt = [0.0, 0.0, 300.0]\n'
STEREO = "pose = {{stereo = {{Tx = {Tx}, Ty = 0.0, Tz = 0.0, Theta = 0.0, Phi = 0.0, Psi = 0.0}}}}\n"


def scene_text(fx="300.0", camera="", tr="[0.1, 0.0, 0.0]", t="[0.0, 0.0, 300.0]", specimen=None,
               second=None, top="") -> str:
    """A 64 × 48 px camera square onto a 40 × 30 mm plate 300 mm away (the CPU backend), with the
    pieces a case replaces; ``second``: camera 1's extra lines (a stereo pose, fx)."""
    text = top + CAMERA.format(name="cam0", fx=fx, extra=camera)
    if second is not None:
        text += CAMERA.format(name="cam1", fx=second.get("fx", "300.0"), extra=STEREO.format(Tx=second.get("Tx", "-50.0")))
    text += specimen if specimen is not None else PLATE.format(tr=tr, t=t)
    return text + '[speckle]\ndot_diameter_px = 4.0\n[render]\nbackend = "cpu"\n'


def inp(nodes, elements) -> str:
    """An Abaqus input of S4R shells (node labels 1…, element labels 1…)."""
    return ("*NODE\n" + "".join(f"{i + 1}, {x!r}, {y!r}, {z!r}\n" for i, (x, y, z) in enumerate(nodes))
            + "*ELEMENT, TYPE=S4R, ELSET=P\n" + "".join(f"{i + 1}, {', '.join(map(str, e))}\n"
                                                       for i, e in enumerate(elements)))


SQUARE = [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0), (0.0, 10.0, 0.0)]
PLATE_INP = Path(__file__).resolve().parents[1] / "examples/plate_inp/plate.inp"


def mesh_case(nodes, elements):
    def make(d: Path) -> Path:
        write(d / "m.inp", inp(nodes, elements))
        return write(d / "s.toml", scene_text(specimen=MESH.format(extra="")))
    return make


def csv_case(d: Path) -> Path:
    """examples/plate_inp with one node of load step 1 moved by 1e308 mm."""
    write(d / "m.inp", PLATE_INP.read_bytes())
    rows = (PLATE_INP.parent / "u_step1.csv").read_text().splitlines()
    rows[2] = rows[2].split(";")[0] + ";1e308;0;0"
    write(d / "u1.csv", "\n".join(rows) + "\n")
    return write(d / "s.toml", scene_text(specimen=MESH.format(extra='csv = ["u1.csv"]\n')))


def text_case(**pieces):
    return lambda d: write(d / "s.toml", scene_text(**pieces))


# each case: d → the scene file, and what the message must say
SCENES = {
    "all nodes equal": (mesh_case([(1.0, 1.0, 0.0)] * 4, [(1, 2, 3, 4)]),
                        "specimen.mesh.path: no element has an area: all its nodes coincide"),
    "collinear nodes": (mesh_case([(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0), (3.0, 0.0, 0.0)], [(1, 2, 3, 4)]),
                        "specimen.mesh.path: no element has an area: all its nodes lie on one line"),
    "collinear off-axis nodes": (mesh_case([(0.1 * k, 0.3 * k, 0.7 * k) for k in range(4)], [(1, 2, 3, 4)]),
                                 "specimen.mesh.path: no element has an area: all its nodes lie on one line"),
    "zero-area elements only": (mesh_case(SQUARE, [(1, 1, 1, 1), (2, 2, 3, 3)]),
                                "specimen.mesh.path: no element has an area: every element is collapsed"),
    "coordinates 1e300": (mesh_case([(0.0, 0.0, 0.0), (1e300, 0.0, 0.0), (1e300, 1e300, 0.0), (0.0, 1e300, 0.0)],
                                    [(1, 2, 3, 4)]),
                          "mesh.nodes: node label 2 lies at [1e+300, 0.0, 0.0] mm (3 of 4 nodes beyond glsim's "
                          "limit of ±1e+09 mm)"),
    "displacement 1e308 (CSV)": (csv_case, "mesh.displacements[1]: load step 1 moves node label 102 by [1e+308, 0.0, "
                                           "0.0] mm"),
    "plate translation 1e308": (text_case(tr="[1e308, 0.0, 0.0]"),
                                "specimen.plate.translations[0]: [1e+308, 0, 0] mm lies beyond glsim's limit of ±1e+09 mm"),
    "specimen t 1e308": (text_case(t="[1e308, 0.0, 300.0]"), "specimen.pose.t: [1e+308, 0, 300] mm lies beyond"),
    "camera t 1e300": (text_case(camera="pose = {t = [0.0, 0.0, 1e300]}\n"), "cameras[0].pose.t: [0, 0, 1e+300] mm"),
    "stereo Tx 1e308": (text_case(second={"Tx": "1e308"}), "cameras[1].pose.stereo.Tx: 1e+308 mm lies beyond"),
    "look_at eye 1e308": (text_case(camera="pose = {look_at = {eye = [0.0, 0.0, -1e308]}}\n"),
                          "cameras[0].pose.look_at.eye: [0, 0, -1e+308] mm lies beyond"),
    "bulge radius 1e300": (text_case(specimen="[specimen.bulge]\nradius = 1e300\n"),
                           "specimen.bulge.radius: 1e+300 mm lies beyond"),
    "k1 1e300": (text_case(camera="distortion = {k1 = 1e300}\n"),
                 "cameras[0].distortion.k1: 1e+300 lies beyond glsim's limit of ±1e+06"),
    "fx 1e300": (text_case(fx="1e300"), "cameras[0].fx: 1e+300 px is more than glsim's limit of 1e+07 px"),
    "camera 1 fx 1e300": (text_case(second={"fx": "1e300"}), "cameras[1].fx: 1e+300 px is more than"),
    "skew 1e300": (text_case(camera="skew = 1e300\n"), "cameras[0].skew: 1e+300 px lies beyond"),
    "camera looking away": (text_case(t="[0.0, 0.0, -300.0]"),
                            "cameras[0]: camera cam0 looks away from the specimen: the specimen's centre lies 300 mm "
                            "behind it"),
    "camera centre on the specimen plane": (text_case(t="[0.0, 0.0, 0.0]"),
                                            "cameras[0]: camera cam0 sees the specimen edge-on or not at all"),
    "seed of 401 digits": (text_case(top=f"seed = 1{'0' * 400}\n"), "seed: 1000"),
    "exposure velocity 1e308": (lambda d: write(d / "s.toml", scene_text() + "[exposure]\ntime = 1.0\nsamples = 4\n"
                                                "velocity = [1e308, 0.0, 0.0]\n"),
                                "exposure.velocity: [1e+308, 0.0, 0.0] mm/s moves the specimen 5e+307 mm"),
    "optics focal length 1e300": (lambda d: write(d / "s.toml", scene_text() + "[optics]\nfocal_length = 1e300\n"
                                                  "f_number = 2.0\nfocus_distance = 1e308\npixel_pitch = 0.005\n"),
                                  "optics.focal_length: 1e+300 mm lies beyond"),
    "specimen within the focal length": (lambda d: write(d / "s.toml", scene_text() + "[optics]\nfocal_length = 400.0\n"
                                                         "f_number = 8.0\nfocus_distance = 500.0\n"
                                                         "pixel_pitch = 0.005\n"),
                                         "optics.focal_length: camera cam0: the specimen comes"),
}
# messages that blamed another key before: they must not come back
WRONG = {"camera looking away": "fx:", "camera centre on the specimen plane": "fx:", "fx 1e300": "speckle",
         "camera 1 fx 1e300": "speckle"}


def refuse(d: Path, scene: Path, backend: str, capsys) -> str:
    """Render ``scene`` with ``backend`` through the CLI; the error it printed (exit status 2, the
    fix after the problem, no traceback, nothing written: ``d`` unchanged and no ``out``)."""
    before = files(d)
    assert main(["render", str(scene), "-o", str(d / "out"), "-q", "--backend", backend]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and " — " in err, err
    assert files(d) == before and not (d / "out").exists()
    return err


@pytest.mark.parametrize("case", list(SCENES))
def test_a_hostile_scene_is_refused_by_name_at_its_root_writing_nothing(tmp_path, capsys, case):
    make, culprit = SCENES[case]
    err = refuse(tmp_path, make(tmp_path), "cpu", capsys)
    assert culprit in err, err
    assert case not in WRONG or WRONG[case] not in err, err


@pytest.mark.gl
@pytest.mark.parametrize("case", list(SCENES))
def test_the_gl_backend_refuses_a_hostile_scene_with_the_cpu_backends_words(tmp_path, capsys, case):
    make, _ = SCENES[case]
    scene = make(tmp_path)
    assert refuse(tmp_path, scene, "gl", capsys) == refuse(tmp_path, scene, "cpu", capsys)


def test_values_at_the_limits_are_accepted_just_beyond_them_refused(tmp_path):
    """The bounds are inclusive: a scene at every limit loads; a hair beyond, the key is named."""
    at = {"fx": "1e7", "camera": "skew = 1e7\ndistortion = {k1 = 1e6, k6 = -1e6}\npose = {t = [1e9, 0.0, 0.0]}\n",
          "tr": "[-1e9, 0.0, 0.0]"}
    scene = load_scene(write(tmp_path / "at.toml", scene_text(**at).replace("cx = 31.5", "cx = -1e7")))
    cam = scene.cameras[0]
    assert (cam.fx, cam.skew, cam.cx, cam.distortion.k1, cam.distortion.k6, cam.t[0]) == (
        MAX_FOCAL_PX, MAX_FOCAL_PX, -MAX_FOCAL_PX, MAX_DISTORTION, -MAX_DISTORTION, MAX_COORDINATE_MM)
    beyond = {"cameras[0].fy": scene_text().replace("fy = 300.0", "fy = 1.0000001e7"),
              "cameras[0].cy": scene_text().replace("cy = 23.5", "cy = -1.0000001e7"),
              "cameras[0].distortion.s4": scene_text(camera="distortion = {s4 = 1.000001e6}\n"),
              "cameras[0].pose.t": scene_text(camera="pose = {t = [0.0, 1.000001e9, 0.0]}\n"),
              "specimen.plate.translations[0]": scene_text(tr="[0.0, 0.0, -1.000001e9]")}
    for key, text in beyond.items():
        with pytest.raises(SceneError) as exc:
            load_scene(write(tmp_path / "beyond.toml", text))
        assert exc.value.key == key, str(exc.value)


def test_a_camera_built_in_python_is_checked_when_it_joins_a_scene(tmp_path):
    """Scene.replace goes through the same checks as a scene file (the key by position)."""
    scene = load_scene(write(tmp_path / "s.toml", scene_text(second={})))
    far = Camera(name="cam1", size=(64, 48), fx=300.0, fy=300.0, cx=31.5, cy=23.5, t=(0.0, 0.0, 1e12))
    with pytest.raises(SceneError, match=r"^cameras\[1\]\.pose: puts camera cam1 1e\+12 mm from the world origin"):
        scene.replace(cameras=(scene.cameras[0], far))
    wide = Camera(name="cam1", size=(64, 48), fx=1e300, fy=300.0, cx=31.5, cy=23.5)
    with pytest.raises(SceneError, match=r"^cameras\[1\]\.fx: 1e\+300 px"):
        scene.replace(cameras=(scene.cameras[0], wide))


@pytest.mark.filterwarnings("ignore::glsim.errors.RenderWarning")   # grazing, unseen: expected at these values
def test_the_cpu_backend_renders_scenes_at_the_limits_without_error(tmp_path):
    """The CPU oracle's pixel boxes stay finite at the limits (they were NaN at k1 = 1e300, skew = 1e300)."""
    for name, pieces in {"k1": {"camera": "distortion = {k1 = 1e6}\n"},
                         "k3 k6": {"camera": "distortion = {k3 = -1e6, k6 = 1e6}\n"},
                         "skew": {"camera": "skew = 1e7\n"}, "translation": {"tr": "[1e9, 0.0, 0.0]"}}.items():
        d = tmp_path / name.replace(" ", "_")
        scene = write(d / "s.toml", scene_text(**pieces))
        assert main(["render", str(scene), "-o", str(d / "out"), "-q", "--backend", "cpu"]) == 0, name
        assert sorted(os.listdir(d / "out")) >= ["cam0_0000.tif", "cam0_0001.tif"]


@pytest.mark.gl
@pytest.mark.filterwarnings("ignore::glsim.errors.RenderWarning")   # elements beyond the valid radius: expected
def test_gl_renders_the_scene_at_the_limits_as_the_cpu_backend_does(tmp_path, gl_ctx):
    """At the distortion limit both backends render, and see the specimen in the same pixels."""
    from glsim.render import Renderer
    scene = load_scene(write(tmp_path / "s.toml", scene_text(camera="distortion = {k3 = -1e6, k6 = 1e6}\n")))
    masks = []
    for backend, ctx in (("cpu", None), ("gl", gl_ctx)):
        with Renderer(scene, backend=backend, ctx=ctx) as r:
            masks.append(r.render(0, 1, truth=True).truth.mask)
    assert masks[0].any() and np.array_equal(masks[0], masks[1])


def test_surface_normal_and_mesh_refuse_what_would_overflow():
    """The roots themselves: the plane fit refuses weights without area (it raised LinAlgError), and
    a Mesh refuses nodes and displacements beyond ±MAX_COORDINATE_MM by node label."""
    with pytest.raises(SceneError, match="^specimen: has no surface to fit a plane to"):
        surface_normal(np.zeros((4, 3)), np.zeros(4))
    nodes = np.array(SQUARE)
    labels = np.array([11, 12, 13, 14])
    with pytest.raises(SceneError, match=r"^mesh.nodes: node label 13 lies at \[10.0, 10.0, -2000000000.0\] mm \(1 of 4 nodes beyond"):
        Mesh(nodes + [0, 0, -2e9] * (np.arange(4) == 2)[:, None], np.array([[0, 1, 2, 3]]), labels, np.array([1]))
    far = np.zeros((4, 3))
    far[3, 1] = 5e9
    with pytest.raises(SceneError, match=r"^mesh.displacements\[1\]: load step 1 moves node label 14 by \[0.0, 5000000000.0"):
        Mesh(nodes, np.array([[0, 1, 2, 3]]), labels, np.array([1]), (np.zeros((4, 3)), far))


# ---- [vary] draws --------------------------------------------------------------------------------------

def spec(d: Path, key: str, table: str) -> Path:
    write(d / "base.toml", scene_text())
    return write(d / "spec.toml", f'scene = "base.toml"\nseed = 1\ncameras = ["cam0"]\nsteps = [0]\n[vary]\n"{key}" = {table}\n')


BIG = "1" + "0" * 400
SPECS = {
    "integers beyond int64": ("speckle.seed", "{integers = [0, 100000000000000000000000], n = 2}",
                              "vary.speckle.seed.integers: 100000000000000000000000 is beyond 64-bit integers"),
    "integers below int64": ("speckle.seed", "{integers = [-9223372036854775809, 0], n = 2}",
                             "vary.speckle.seed.integers: -9223372036854775809 is beyond 64-bit integers"),
    "uniform spanning 2e308": ("noise.sigma", "{uniform = [-1e308, 1e308], n = 2}",
                               "vary.noise.sigma.uniform: [-1e+308, 1e+308] spans more than a float can hold"),
    "normal std 1e308": ("noise.sigma", "{normal = [0, 1e308], n = 2}",
                         "vary.noise.sigma.normal: [0, 1e+308] reaches beyond what a float can hold"),
    "range spanning 2e308": ("noise.sigma", "{range = [-1e308, 1e308, 1e307]}",
                             "vary.noise.sigma.range: [-1e+308, 1e+308, 1e+307] spans more than a float can hold"),
    "linspace spanning 2e308": ("noise.sigma", "{linspace = [-1e308, 1e308, 3]}",
                                "vary.noise.sigma.linspace: [-1e+308, 1e+308, 3] spans more than a float can hold"),
    "range to a 401-digit integer": ("speckle.seed", f"{{range = [0, {BIG}]}}",
                                     "vary.speckle.seed.range: 100000000000000000000000… (401 digits) is beyond "
                                     "64-bit integers"),
    "choice of a 401-digit integer": ("speckle.seed", f"{{choice = [{BIG}], n = 1}}",
                                      "speckle.seed: 1000"),
}


@pytest.mark.parametrize("case", list(SPECS))
def test_a_hostile_vary_draw_is_refused_by_name_writing_nothing(tmp_path, capsys, case):
    key, table, culprit = SPECS[case]
    s = spec(tmp_path, key, table)
    before = files(tmp_path)
    assert main(["library", str(s), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert culprit in err and "Traceback" not in err and " — " in err, err
    assert files(tmp_path) == before and not (tmp_path / "out").exists()


def test_the_largest_int64_draw_is_drawn():
    """[-2⁶³, 2⁶³) is numpy's whole int64 range: accepted, and its draws are integers in it."""
    from glsim.workflows.library.spec import _Key
    values = _Key("speckle.seed", {"integers": [-2 ** 63, 2 ** 63], "n": 50}, "grid", 1).values
    assert len(values) == 50 and all(isinstance(v, int) and -2 ** 63 <= v < 2 ** 63 for v in values)
    assert len(set(values)) == 50


# ---- rig files -----------------------------------------------------------------------------------------

RIGS = {
    "empty .yaml": ("rig.yaml", b"", "rig.yaml: is empty"),
    "blank .yaml": ("rig.yaml", b"\n  \n", "rig.yaml: is empty"),
    "binary .yaml": ("rig.yaml", b"garbage: [1, 2\n\x00\xff", "rig.yaml: is not UTF-8 text"),
    "NUL in .yaml": ("rig.yaml", b"K1: 1\n\x00\n", "rig.yaml: holds a NUL byte at character 6"),
    "plain text .yaml": ("rig.yaml", b"just text\n", "rig.yaml: is not an OpenCV FileStorage YAML file (OpenCV: "),
    "YAML of other keys": ("rig.yaml", b"%YAML:1.0\n---\nfoo: 1\n", "rig.yaml: has no K1, D1, K2, D2, R, T, image_size"),
    "a 2 x 2 K1": ("rig.yaml", b"%YAML:1.0\n---\n" + b"".join(
        k.encode() + b": !!opencv-matrix\n   rows: " + r + b"\n   cols: " + c + b"\n   dt: d\n   data: [" + v + b"]\n"
        for k, r, c, v in (("K1", b"2", b"2", b"1, 0, 0, 1"), ("K2", b"3", b"3", b"1, 0, 0, 0, 1, 0, 0, 0, 1"),
                           ("D1", b"1", b"5", b"0, 0, 0, 0, 0"), ("D2", b"1", b"5", b"0, 0, 0, 0, 0"),
                           ("R", b"3", b"3", b"1, 0, 0, 0, 1, 0, 0, 0, 1"), ("T", b"3", b"1", b"1, 0, 0"),
                           ("image_size", b"1", b"2", b"64, 48"))), "rig.yaml: K1: holds 4 values ((2, 2)), not 9"),
    "2 MB .yaml": ("rig.yaml", b"#" * (2 << 20), "rig.yaml: is 2,097,152 bytes, more than a rig file's 1,048,576"),
    "binary .caldat": ("rig.caldat", b"\x00\xff\xfe garbage", "rig.caldat: is not UTF-8 text"),
}


@pytest.mark.parametrize("case", list(RIGS))
def test_rig_export_of_a_garbage_rig_file_is_refused_by_name_writing_nothing(tmp_path, capsys, case):
    name, content, culprit = RIGS[case]
    src = write(tmp_path / name, content)
    before = files(tmp_path)
    assert main(["rig", "export", str(src), "-o", str(tmp_path / "out.json"), "--size", "64", "48"]) == 2
    err = capsys.readouterr().err
    assert culprit in err and "Traceback" not in err and " — " in err, err
    assert files(tmp_path) == before


def test_a_directory_or_fifo_named_as_a_rig_file_is_named_as_such(tmp_path, capsys):
    fifo = tmp_path / "rig.yaml"
    os.mkfifo(fifo)
    assert main(["rig", "export", str(fifo), "-o", str(tmp_path / "out.json")]) == 2
    assert "rig.yaml: is a FIFO (named pipe), not a file" in capsys.readouterr().err


# ---- the command line, in its own process --------------------------------------------------------------

@pytest.mark.process
@pytest.mark.slow
def test_the_cli_exits_2_without_a_traceback_under_a_500_MB_limit(tmp_path):
    """`glsim` in a fresh process (address space capped at 500 MB): exit status 2, the named error on
    stderr, no traceback, nothing written."""
    cases = {}
    for case in ("all nodes equal", "coordinates 1e300", "camera looking away", "k1 1e300", "fx 1e300"):
        d = tmp_path / f"c{len(cases)}"
        cases[case] = (["render", str(SCENES[case][0](d)), "-o", str(d / "out"), "--backend", "cpu"], d, SCENES[case][1])
    d = tmp_path / "rig"
    cases["empty rig"] = (["rig", "export", str(write(d / "rig.yaml", b"")), "-o", str(d / "o.json")], d,
                          "rig.yaml: is empty")
    d = tmp_path / "spec"
    key, table, culprit = SPECS["integers beyond int64"]
    cases["integers"] = (["library", str(spec(d, key, table)), "-o", str(d / "out")], d, culprit)
    script = ("import resource, sys\n"
              "resource.setrlimit(resource.RLIMIT_AS, (500 << 20, 500 << 20))\n"
              "from glsim.cli import main\n"
              "sys.exit(main(sys.argv[1:]))\n")
    for case, (argv, d, culprit) in cases.items():
        before = files(d)
        r = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, (case, r.returncode, r.stderr)
        assert culprit in r.stderr and "Traceback" not in r.stderr, (case, r.stderr)
        assert files(d) == before, case
        assert not any(p.name in ("out", "o.json") for p in d.iterdir()), case
