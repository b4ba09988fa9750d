"""docs/shaders.md shows the pass × define tables that plan() gives today."""
from pathlib import Path

from glsim.backends.gl import passtable

PAGE = Path(__file__).resolve().parents[1] / "docs" / "shaders.md"


def test_the_page_holds_the_generated_pass_tables():
    """The tables between the page's markers are glsim.backends.gl.passtable.markdown() verbatim
    (regenerate: python -m glsim.backends.gl.passtable)."""
    text = PAGE.read_text()
    start = "<!-- pass table: python -m glsim.backends.gl.passtable -->\n"
    assert start in text and "<!-- end pass table -->" in text
    body = text.split(start, 1)[1].split("<!-- end pass table -->", 1)[0]
    assert body == passtable.markdown()


def test_the_tables_name_every_packaged_entry_and_no_other():
    """Every pass of the tables is a packaged entry file, and every packaged .frag and .comp a
    plan runs is in them (the rest: the probe and filter glsim check and the geometry run)."""
    from importlib import resources

    files = {f.name for f in resources.files("glsim.shaders").iterdir() if f.name.endswith((".frag", ".comp"))}
    rows = {line.split("`")[1] for line in passtable.markdown().split("\n\n")[0].splitlines()[2:]}
    assert rows <= files
    assert files - rows == {"fp64_probe.comp", "shape.comp"}


def test_the_define_table_is_the_plans():
    """A plan's deformation pass is marked with each of the plan's defines: spot checks against
    plan() itself (truth only where a pass runs at 1 spp; float64 never in mode fast)."""
    table = passtable.markdown().split("\n\n")[1].splitlines()
    header = [c.strip(" `") for c in table[0].split("|")[2:-1]]
    marks = {row.split("|")[1].strip(" `"): dict(zip(header, (c.strip() for c in row.split("|")[2:-1])))
             for row in table[2:]}
    assert marks["FP64"]["fast.frag"] == "" and marks["FP64"]["single.frag"] == "•"
    assert marks["TRUTH"]["subsamples.frag"] == "" and marks["TRUTH"]["single.comp"] == "•"
    assert marks["MODE_Q4"]["subsamples.frag"] == "" and marks["MODE_EXACT"]["subsamples.frag"] == "•"
    want = set()
    for p in passtable.plans():
        if any(ps.shader == "overflow.frag" for ps in p.passes):
            want |= set(p.define_dict)
    assert {name for name, row in marks.items() if row["overflow.frag"]} == want
