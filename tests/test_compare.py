"""glsim compare: a DIC result against the truth of a render, checked on a plate whose truth has
a closed form (camera 0's ray met with the plane z = 600 mm, then the rigid shift)."""
import numpy as np
import pytest

from glsim.cli import main as glsim
from glsim.scene import Plate, Render, Scene, Specimen, bulge_scene
from glsim.scene.camera import pixel_rays
from glsim.workflows.sequence import write_sequence

SHIFT = np.array([0.3, -0.2, 0.1])       # mm, step 1 (world = camera 0's frame)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    cam = bulge_scene(size=(96, 72)).cameras[0]
    scene = Scene(cameras=(cam,), render=Render(backend="cpu"),
                  specimen=Specimen(plate=Plate(width=80, height=60, nx=3, ny=2,
                                                translations=(tuple(SHIFT),)), t=(0.0, 0.0, 600.0)))
    write_sequence(scene, out)
    return out, cam


def _closed_form(cam, uv):
    d, ok = pixel_rays(uv, cam)
    assert ok.all()
    return d * (600.0 / d[:, 2:3])          # the undeformed point on z = 600 (camera 0 at the origin)


def test_compare_recovers_a_known_bias(rendered, tmp_path, capsys):
    out, cam = rendered
    rng = np.random.default_rng(1)
    uv = np.column_stack([rng.uniform(30, 66, 40), rng.uniform(25, 47, 40)])
    X0 = _closed_form(cam, uv)
    bias = np.array([1e-3, -2e-3, 5e-3])
    noise = rng.normal(0, 1e-4, (40, 3))
    U = SHIFT + bias + noise
    csv = tmp_path / "dic.csv"
    rows = ["u,v,X,Y,Z,U,V,W"] + [",".join(repr(float(x)) for x in (*p, *(x0 + u), *u)) for p, x0, u in zip(uv, X0, U)]
    csv.write_text("\n".join(rows) + "\n")
    assert glsim(["compare", str(csv), "--truth", str(out), "--step", "1", "-o", str(tmp_path / "cmp")]) == 0
    import json
    res = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert res["n_compared"] == 40
    by = {r["dir"]: r for r in res["rows"]}
    for j, (x, u) in enumerate((("X", "U"), ("Y", "V"), ("Z", "W"))):
        for name in (x, u):
            assert by[name]["mean_mm"] == pytest.approx(bias[j] + noise[:, j].mean(), abs=1e-9)
            assert by[name]["std_mm"] == pytest.approx(noise[:, j].std(), abs=1e-9)
    assert res["mm_per_px"] == pytest.approx(600.0 / cam.fx, rel=1e-3)
    assert (tmp_path / "cmp" / "compare.png").read_bytes()[:4] == b"\x89PNG"
    assert "| W |" in capsys.readouterr().out


def test_compare_names_what_is_missing(rendered, tmp_path, capsys):
    out, _ = rendered
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,Z\n1,2,3\n")
    assert glsim(["compare", str(bad), "--truth", str(out), "--step", "1"]) == 2
    err = capsys.readouterr().err
    assert "the header has x, y, Z; needed: u, v and X, Y, Z and/or U, V, W" in err
    good = tmp_path / "good.csv"
    good.write_text("u,v,U,V,W\n48,36,0,0,0\n")
    assert glsim(["compare", str(good), "--truth", str(out), "--step", "5"]) == 2
    assert "--step 5:" in capsys.readouterr().err and not (tmp_path / "compare").exists()


@pytest.mark.parametrize("sep", [";", "\t", " ", ","])
def test_compare_reads_the_separators_dic_programs_write(sep, tmp_path):
    """Issue 29: a MatchID-style ';' export (decimal commas too) was refused."""
    from glsim.workflows.compare import read_result

    rows = [["u", "v", "U", "V", "W"], ["48", "36.5", "0.25", "-0.1", "0"], ["50", "30", "1e-3", "0", "0"]]
    text = "\n".join(sep.join(r) for r in rows) + "\n"
    if sep in ";\t":
        text = text.replace("36.5", "36,5").replace("0.25", "0,25")
    (tmp_path / "dic.csv").write_text(text)
    res = read_result(tmp_path / "dic.csv")
    np.testing.assert_array_equal(res["uv"], [[48, 36.5], [50, 30]])
    np.testing.assert_array_equal(res["U"], [[0.25, -0.1, 0], [1e-3, 0, 0]])


def test_compare_says_a_header_only_file_has_no_data_rows(rendered, tmp_path, capsys):
    out, _ = rendered
    (tmp_path / "head.csv").write_text("u;v;U;V;W\n")
    assert glsim(["compare", str(tmp_path / "head.csv"), "--truth", str(out), "--step", "1"]) == 2
    assert "no data rows" in capsys.readouterr().err
    (tmp_path / "short.csv").write_text("u,v,U,V,W\n1,2,0,0,0\n1,2,0\n")
    assert glsim(["compare", str(tmp_path / "short.csv"), "--truth", str(out), "--step", "1"]) == 2
    assert "data row 2 has 3 values, the header 5" in capsys.readouterr().err


def test_compare_map_colour_bar_shows_the_errors_without_an_offset(tmp_path, monkeypatch):
    """Issue 29: errors of 1e-2 ± 1e-13 mm were labelled "1e-13 + 1e-2"."""
    from types import SimpleNamespace

    from glsim.workflows import compare

    figs = []
    monkeypatch.setattr(compare, "save_figure", lambda fig, path, dpi: figs.append(fig) or path)
    n = 20
    U = np.zeros((n, 3))
    U[:, 0] = 1e-2 + np.linspace(0, 1e-13, n)
    result = {"uv": np.random.default_rng(0).uniform(0, 50, (n, 2)), "valid": np.ones(n, bool), "U": U}
    truth = SimpleNamespace(displacement=np.zeros((n, 3)), X_deformed=None, valid=np.ones(n, bool))
    compare.plot_map(result, truth, tmp_path / "map.png")
    figs[0].canvas.draw()
    bar = figs[0].axes[-1]
    assert bar.yaxis.get_offset_text().get_text() == ""
