"""Issue 9, messages: each one names the field, the culprit and the fix, as a new user met them
(scene files written by hand, rendered with `glsim render`, calibrated with `glsim calib`)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from _user_scene import CAMERA, FIRST_LABEL, n_nodes, write_mesh, write_scene
from glsim.cli import main
from glsim.errors import SceneError
from glsim.scene import load_scene
from glsim.workflows.calib.cli import error_lines, main as calib_main


def _render_error(scene_file, tmp_path, capsys) -> str:
    out = tmp_path / "out"
    assert main(["render", str(scene_file), "-o", str(out), "-q"]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


# --- silent wrong results, now refused --------------------------------------------------------------

@pytest.mark.parametrize("key, value", [("dot_diameter_px", "6.0"), ("density", "0.4"), ("seed", "3"),
                                        ("oversample", "3.0"), ("edge_px", "2.0")])
def test_generator_keys_with_an_image_are_refused_by_name(tmp_path, key, value):
    """The user gave dot_diameter_px together with image; it was ignored without a word."""
    (tmp_path / "ref.png").write_bytes(b"")
    path = tmp_path / "s.toml"
    path.write_text(CAMERA + f"[speckle]\nimage = 'ref.png'\nmm_per_px = 0.1\n{key} = {value}\n")
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    assert str(exc.value) == (f"speckle.{key}: is a setting of the built-in speckle generator, which is not "
                              f"used with speckle.image = 'ref.png' — remove {key} (the image is used as it "
                              "is), or remove image to generate the pattern")


def test_a_written_scene_json_with_an_image_loads_back(tmp_path):
    """scene.json spells out every default: the generator keys at their defaults pass."""
    import tifffile
    tifffile.imwrite(tmp_path / "ref.tif", np.zeros((700, 1200), np.uint8))
    scene = load_scene(write_scene(tmp_path, extra="[speckle]\nimage = 'ref.tif'\nmm_per_px = 0.1\n"))
    (tmp_path / "scene.json").write_text(scene.to_json())
    assert load_scene(tmp_path / "scene.json") == scene


def test_two_component_displacements_are_refused(tmp_path, capsys):
    n = n_nodes()
    arrays = {"u1": np.zeros((n, 3)), "u2": np.full((n, 2), 0.01)}
    write_mesh(tmp_path / "plate.vtu", arrays)
    err = _render_error(write_scene(tmp_path, mesh=False), tmp_path, capsys)
    assert ("plate.vtu: point-data array 'u2' (load step 2) has 2 components per node, not 3 (ux, uy, uz) — "
            "write the displacement with 3 components (uz = 0 for a plane field)") in err


@pytest.mark.parametrize("where, table", [("cameras[0].pose.rvec", "camera"), ("specimen.pose.rvec", "specimen")])
def test_rvec_in_degrees_is_refused_with_the_hint(tmp_path, where, table):
    """The user wrote rvec = [0, 20, 0] meaning 20°."""
    path = write_scene(tmp_path)
    text = path.read_text()
    if table == "camera":
        text = text.replace("cy = 29.5\n", "cy = 29.5\npose = {rvec = [0.0, 20.0, 0.0]}\n")
    else:
        text = text.replace("t = [0.0, 0.0, 800.0]", "rvec = [0.0, 20.0, 0.0]\nt = [0.0, 0.0, 800.0]")
    path.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    assert str(exc.value) == (f"{where}: [0.0, 20.0, 0.0] turns by |rvec| = 20 rad (1146°), more than π: it "
                              "looks like degrees — rvec is in radians (axis × angle): write [0, 0.3491, 0] for "
                              "these degrees, or give the rotation as R")


def test_rvec_up_to_pi_is_accepted(tmp_path):
    path = write_scene(tmp_path)
    path.write_text(path.read_text().replace("t = [0.0, 0.0, 800.0]", "rvec = [0.0, 0.0, 3.14159]\nt = [0.0, 0.0, 800.0]"))
    assert load_scene(path).specimen.R[0][0] == pytest.approx(-1.0)


# --- messages that name the culprit -----------------------------------------------------------------

def test_nan_in_a_displacement_array_names_array_step_node_and_count(tmp_path, capsys):
    """Was: mesh.displacements[2]: shape (231, 3) or values are not (231, 3) finite."""
    arrays = write_mesh(tmp_path / "plate.vtu")
    arrays["u2"][[5, 9, 20]] = np.nan
    write_mesh(tmp_path / "plate.vtu", arrays)
    err = _render_error(write_scene(tmp_path, mesh=False), tmp_path, capsys)
    assert (f"plate.vtu: point-data array 'u2' (load step 2) has non-finite (NaN or inf) displacements at 3 of "
            f"{n_nodes()} nodes, first at node label {FIRST_LABEL + 5}: [nan, nan, nan] — give finite numbers") in err


def test_nan_in_a_csv_names_line_step_and_label(tmp_path, capsys):
    write_scene(tmp_path)
    lines = ["label;ux;uy;uz"] + [f"{FIRST_LABEL + i};0;0;0" for i in range(n_nodes())]
    lines[3] = f"{FIRST_LABEL + 2};nan;0;0"
    (tmp_path / "u1.csv").write_text("\n".join(lines))
    (tmp_path / "u2.csv").write_text("\n".join(lines))
    path = tmp_path / "scene.toml"
    path.write_text(path.read_text().replace('point_data = ["u1", "u2"]', 'csv = ["u2.csv", "u1.csv"]'))
    err = _render_error(path, tmp_path, capsys)
    assert (f"u2.csv:4: load step 1: non-finite (NaN or inf) displacement [nan, 0.0, 0.0] of node label "
            f"{FIRST_LABEL + 2} (1 such lines in the file)") in err


def test_a_wrong_point_data_name_hints_at_the_scene_key(tmp_path, capsys):
    """Was: … set point_data_steps to names from that list (not a scene key)."""
    err = _render_error(write_scene(tmp_path, point_data=("u1", "U2")), tmp_path, capsys)
    assert ("plate.vtu: has no point-data array 'U2' (point_data[1], load step 2); it has: node_id, u1, u2 — "
            'set specimen.mesh.point_data to names from that list, one array per load step after the reference, '
            'e.g. ["node_id", "u1", "u2"]') in err
    assert "point_data_steps" not in err


# --- glsim calib -----------------------------------------------------------------------------------

def test_calib_errors_have_units_and_the_largest_is_marked():
    """Was: errors without units, and cx2 = +1.55 px (the largest) only in report.json."""
    names = ["fx1", "fy1", "cx1", "cy1", "k1_1", "k2_1", "p1_1", "p2_1", "k3_1", "fx2", "fy2", "cx2", "cy2",
             "k1_2", "k2_2", "p1_2", "p2_2", "k3_2", "Tx", "Ty", "Tz", "Theta", "Phi", "Psi"]
    e = {n: 0.01 for n in names} | {"cx2": 1.55, "Ty": -0.3, "Psi": 0.02, "k1_2": 0.05,
                                    "T_norm": 0.31, "rotation_deg": 0.03}
    lines = error_lines(e)
    text = "\n".join(lines)
    for n in names:                                         # every parameter is printed
        assert f"{n} " in text
    assert "  fx2 +0.01 px,  fy2 +0.01 px,  cx2 +1.55 px ◀,  cy2 +0.01 px" in lines
    assert "  Tx +0.01 mm,  Ty -0.3 mm ◀,  Tz +0.01 mm" in lines
    assert "  Theta +0.01 deg,  Phi +0.01 deg,  Psi +0.02 deg ◀" in lines
    assert lines[-1] == "largest: cx2 +1.55 px, Ty -0.3 mm, Psi +0.02 deg, k1_2 +0.05 (distortion)"


@pytest.mark.workflow
@pytest.mark.gl
def test_calib_library_draws_until_it_has_the_usable_pairs(tmp_path, capsys):
    """Was: --pairs 3 wrote a library with fewer usable pairs, which calib run then refused."""
    lib = tmp_path / "lib"
    args = ["library", "default", "--scale", "0.25", "--spp", "4", "--noise", "0", "-o", str(lib)]
    assert calib_main(args + ["--pairs", "3"]) == 0
    out = capsys.readouterr().out
    drawn = len(list((lib / "pairs").glob("*.json")))
    assert f"{drawn} pairs drawn in {lib}: " in out and "usable by `glsim calib run` (3 asked for" in out
    assert calib_main(["run", str(lib), "-o", str(tmp_path / "cal")]) == 0
    report = json.loads((tmp_path / "cal" / "report.json").read_text())
    assert report["pairs_used"] >= 3
    run_out = capsys.readouterr().out
    assert "px ◀" in run_out and "largest: " in run_out
    # not enough usable pairs within --max-pairs: the library itself says so
    few = tmp_path / "few"
    assert calib_main(["library", "default", "--scale", "0.25", "--spp", "4", "--noise", "0", "-o", str(few),
                       "--pairs", "3", "--max-pairs", "3", "--min-points", "81"]) == 2
    err = capsys.readouterr().err
    assert "pairs: only " in err and "of the 3 pairs drawn are usable (both cameras detect ≥ 81 common dots), " \
                                     "3 were asked for" in err and "--max-pairs" in err
    assert len(list((few / "pairs").glob("*.json"))) == 3    # the drawn pairs are kept for a rerun


@pytest.mark.gl
def test_info_prints_the_glsl_version(capsys):
    assert main(["info"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("glsl"))
    version = line.split(None, 1)[1]
    assert version[0].isdigit() and "." in version            # e.g. 4.50
