"""The report's web page: real tables, headings, figures and escaped text."""

from models.report import markdown_table
from sim2real.report_html import blocks, render_html


def test_lines_and_tables_become_blocks_and_the_first_paragraph_leads():
    items = [
        "# Title",
        "",
        "The gap is 60 % `physics` (air damping);",
        "**4 %** is left.",
        "",
        "![shares.png](shares.png)",
        "## Evidence",
        "- one item",
        "  continued",
        "- two",
        markdown_table(["factor", "share"], [["a<b", "60 %"], ["`c`", "4 %"]]),
    ]
    got = blocks(items)
    assert [b["kind"] for b in got] == ["h1", "p", "figure", "h2", "ul", "table"]
    assert got[1]["lead"] and ("code", "physics") in got[1]["spans"]
    assert ("strong", "4 %") in got[1]["spans"]
    assert got[4]["items"][0] == [("text", "one item continued")]
    assert got[5]["header"] == [[("text", "factor")], [("text", "share")]]
    assert got[5]["rows"][1][0] == [("code", "c")]


def test_the_page_escapes_text_and_shows_tables_as_html():
    table = markdown_table(["factor", "share"], [["<script>x</script>", "60 %"]])
    page = render_html(["# Report <1>", "", "Answer & more.", table], "Report <1>")
    assert "<script>" not in page and "&lt;script&gt;" in page
    assert "<title>Report &lt;1&gt;</title>" in page
    assert "<th>factor</th>" in page and "<td>60 %</td>" in page
    assert '<p class="answer">Answer &amp; more.</p>' in page
    assert str(table).startswith("| factor | share |")  # the Markdown text is unchanged


def test_the_report_says_how_the_factors_were_chosen():
    from sim2real.report import _selection_lines

    path = [
        {
            "step": 1,
            "added": "visual.defocus_blur",
            "screened": {},
            "measured": {"scene.pose": 0.09, "visual.defocus_blur": 0.46},
        },
        {"step": 2, "added": None, "screened": {}, "measured": {"scene.pose": 0.47}},
        {"round": 1, "factor": "visual.defocus_blur", "tried": [], "closure": [], "kept": 3.0},
    ]
    lines = _selection_lines(path)
    table = next(line for line in lines if str(line).startswith("| step"))
    rows = str(table).splitlines()[2:]
    assert rows == [
        "| 1 | visual.defocus_blur | visual.defocus_blur 46 %, scene.pose 9 % |",
        "| 2 | none (stop) | scene.pose 47 % |",
    ]
    tied = {"step": 2, "added": None, "screened": {}, "measured": {"a": 0.5, "b": 0.5}}
    table = next(s for s in _selection_lines([{**tied, "tied": ["a", "b"]}]) if "| step" in s)
    assert str(table).splitlines()[2] == "| 2 | none (tied: a, b) | a 50 %, b 50 % |"
    chose = {**tied, "added": "c", "tied": ["a", "b"], "measured": {"c": 0.3}}
    table = next(s for s in _selection_lines([chose]) if "| step" in s)
    assert str(table).splitlines()[2] == "| 2 | c (tied: a, b before it) | c 30 % |"
    kernel = {**tied, "added": "a", "kernel_apart": {"a": ["b"]}, "kernel_beaten": ["d"]}
    table = next(s for s in _selection_lines([kernel]) if "| step" in s)
    assert str(table).splitlines()[2] == (
        "| 2 | a; told from b by the kernel distance; passed over: d (a tied rival removes more "
        "of the kernel distance) | a 50 %, b 50 % |"
    )
    refit = {
        "step": 3,
        "added": "look.texture_mode",
        "refit": {"look.texture_mode": {"visual.compression": 30, "look.texture_mode": "random"}},
        "measured": {"look.texture_mode": 0.8},
    }
    table = next(s for s in _selection_lines([refit]) if "| step" in s)
    assert str(table).splitlines()[2] == (
        "| 3 | look.texture_mode (others refitted around it: visual.compression 30, "
        "look.texture_mode random) | look.texture_mode 80 % |"
    )
    assert not any("dropped if" in str(line) for line in lines)  # no prune step, no word of it
    pruned = {"step": 4, "reset": {"a": 0.02, "b": 0.14}, "dropped": "a"}
    assert any("dropped if" in str(line) for line in _selection_lines([pruned]))
    table = next(s for s in _selection_lines([pruned]) if "| step" in s)
    assert str(table).splitlines()[2] == (
        "| 4 | dropped a (it no longer matters) | reset alone gives back: a 2 %, b 14 % |"
    )
    kept = next(s for s in _selection_lines([{**pruned, "dropped": None}]) if "| step" in s)
    assert str(kept).splitlines()[2].startswith("| 4 | none dropped (each matters) |")
    assert _selection_lines(path[2:]) == []  # a fit of given factors: no selection to show
