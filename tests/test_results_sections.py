"""scripts/results.py's sections that a full run does not write (the whole library's, the
classic peers'): a full run keeps them as they are, and ``--section library`` replaces only its
own. The slow evaluation itself is not run: the section is made from a measured-looking row."""

import sys

from storetools import REPO, load_script

sys.path.insert(0, str(REPO / "scripts"))  # results.py imports its neighbours, as when run as a script
results = load_script("results")
DOC = REPO / "docs" / "results.md"


def section(nn: str) -> str:
    return "\n".join([results.LIBRARY_HEADING, "", "| distance | NN |", "|---|---|", f"| ALL (plain D2) | {nn} |", ""]) + "\n"


def peers_of(text: str) -> str:
    return text[text.index(results.PEERS_HEADING):]


def test_library_section_replaces_only_itself_and_is_idempotent():
    old = DOC.read_text()
    assert results.LIBRARY_HEADING in old and results.PEERS_HEADING in old  # the document has both
    new = results.with_library_section(old, section("0.123"))
    assert "| ALL (plain D2) | 0.123 |" in new and new.count(results.LIBRARY_HEADING) == 1
    assert new[:new.index(results.LIBRARY_HEADING)] == old[:old.index(results.LIBRARY_HEADING)]
    assert peers_of(new) == peers_of(old)  # the peers' section, verbatim after it
    assert results.with_library_section(new, section("0.123")) == new


def test_library_section_goes_before_the_peers_when_missing():
    old = DOC.read_text()
    start = old.index(results.LIBRARY_HEADING)
    without = old[:start] + old[old.index(results.PEERS_HEADING):]
    new = results.with_library_section(without, section("0.5"))
    assert new.index(results.LIBRARY_HEADING) < new.index(results.PEERS_HEADING)
    assert peers_of(new) == peers_of(old)


def test_a_full_run_keeps_both_sections_whole(tmp_path):
    old = DOC.read_text()
    kept, names = results.other_scripts_sections(DOC)
    assert names == [results.LIBRARY_HEADING.lstrip("# "), results.PEERS_HEADING.lstrip("# ")]
    library = old[old.index(results.LIBRARY_HEADING):old.index(results.PEERS_HEADING)].rstrip("\n")
    assert library in kept and peers_of(old).rstrip("\n") in kept
    written = "# Retrieval results\n\nfresh tables\n" + "\n" + kept  # what main() writes
    (tmp_path / "results.md").write_text(written)
    assert results.other_scripts_sections(tmp_path / "results.md") == (kept, names)  # stable when run again
