"""``benchmarks/collect_results.py`` indexes benchmarks/results/ and leaves RESULTS.md alone."""


def test_index_lists_results_by_method_and_leaves_results_page_alone(tmp_path, script):
    results = tmp_path / "results"
    results.mkdir()
    (results / "lsd_speed.md").write_text("## LSD planner speed\n\n| a |\n")
    (results / "lsd_speed.json").write_text("{}")
    (results / "roshan_views.png").write_bytes(b"\x89PNG")
    (results / "scaling.md").write_text("no heading\n")
    page = tmp_path / "RESULTS.md"
    page.write_text("hand-written\n")
    mod = script("benchmarks/collect_results.py")
    assert mod.main(["--results", str(results)]) == 0
    index = (results / mod.INDEX_NAME).read_text()
    assert "## LSD\n\n- [lsd_speed.json](lsd_speed.json), [lsd_speed.md](lsd_speed.md): LSD planner speed" in index
    assert "## ROSHAN\n\n- [roshan_views.png](roshan_views.png)\n" in index
    assert "## Integration and other\n\n- [scaling.md](scaling.md)\n" in index
    assert "Geometry core" not in index  # no empty sections
    assert page.read_text() == "hand-written\n"
    # a second run does not index the index
    mod.main(["--results", str(results)])
    assert "INDEX.md" not in (results / mod.INDEX_NAME).read_text()
