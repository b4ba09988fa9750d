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
