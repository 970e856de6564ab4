"""shapeidx check-new on real KiCad parts and a real store: exit statuses, not-news, leave one out."""

import json
import shutil
import subprocess
import sys

import pytest

PARTS = ["Battery/BatteryHolder_Keystone_500.wrl", "Battery/BatteryHolder_Keystone_104_1x23mm.wrl",
         "Battery/BatteryHolder_Keystone_105_1x2430.wrl"]


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "shapeidx.cli", *args], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def library(data_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp("lib")
    for name in PARTS:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(data_dir / "kicad6" / name, root / name)
    store = root.parent / "lib.shapeidx"
    done = run("build", str(root), "--store", str(store), "--workers", "1", "-q")
    assert done.returncode == 0, done.stderr
    return root, store


def test_copy_is_a_duplicate_and_own_file_is_not_news(library, tmp_path):
    root, store = library
    copy = tmp_path / "copy.wrl"
    shutil.copy(root / PARTS[0], copy)
    done = run("check-new", str(copy), "--store", str(store), "--format", "json")
    assert done.returncode == 7, done.stderr
    report = json.loads(done.stdout)[0]
    assert report["status"] == "duplicate"
    assert report["duplicates"][0]["tier"] == "identical"
    assert report["duplicates"][0]["relative_path"] == PARTS[0]
    own = run("check-new", str(root / PARTS[0]), "--store", str(store))
    assert own.returncode == 0 and "unchanged" in own.stdout
    alone = run("check-new", str(root / PARTS[0]), "--store", str(store), "--exclude-self", "--format", "json")
    assert alone.returncode == 0, alone.stderr
    assert json.loads(alone.stdout)[0]["status"] == "new"


def test_bad_input_is_one_line_and_status_1(library, tmp_path):
    root, store = library
    bad = tmp_path / "bad.wrl"
    bad.write_text("junk\n")
    done = run("check-new", str(bad), "--store", str(store))
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and str(bad) in done.stderr and "Traceback" not in done.stderr
    missing = run("check-new", str(bad), "--store", str(tmp_path / "none.shapeidx"))
    assert missing.returncode == 1


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_git_range(library, tmp_path):
    root, store = library
    repo = tmp_path / "repo"
    repo.mkdir()
    git = lambda *a: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *a], cwd=repo, check=True,
                                    capture_output=True)
    git("init", "-q")
    (repo / "README").write_text("x\n")
    git("add", "README")
    git("commit", "-qm", "start")
    shutil.copy(root / PARTS[1], repo / "dup.wrl")
    git("add", "dup.wrl")
    git("commit", "-qm", "add a duplicate")
    done = run("check-new", "--git", "HEAD", "--store", str(store), cwd=repo)
    assert done.returncode == 7, done.stderr
    assert "ALREADY IN THE LIBRARY" in done.stdout and PARTS[1] in done.stdout


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_pre_commit_refuses_a_duplicate_and_passes_a_new_part(library, tmp_path, data_dir):
    import os

    root, store = library
    repo = tmp_path / "vault"
    repo.mkdir()
    env = {**os.environ, "PRE_COMMIT_HOME": str(tmp_path / "pc-home"), "GIT_AUTHOR_NAME": "t",
           "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t"}
    git = lambda *a: subprocess.run(["git", *a], cwd=repo, capture_output=True, text=True, env=env)
    git("init", "-q")
    entry = f"{sys.executable} -m shapeidx.cli check-new --store {store}"
    (repo / ".pre-commit-config.yaml").write_text(
        "repos:\n  - repo: local\n    hooks:\n      - {id: shapeidx-check-new, name: shapeidx check-new,"
        f" entry: '{entry}', language: system, files: '\\.wrl$'}}\n")
    git("add", ".pre-commit-config.yaml")
    assert git("commit", "-qm", "config").returncode == 0
    hook = subprocess.run([sys.executable, "-m", "pre_commit", "install"], cwd=repo, capture_output=True, text=True, env=env)
    assert hook.returncode == 0, hook.stderr
    shutil.copy(root / PARTS[2], repo / "dup.wrl")
    git("add", "dup.wrl")
    refused = git("commit", "-m", "add a duplicate")
    assert refused.returncode != 0
    assert "ALREADY IN THE LIBRARY" in refused.stdout + refused.stderr
    git("rm", "-q", "--cached", "dup.wrl")
    shutil.copy(data_dir / "kicad6" / "Mounting_Wuerth" / "Mounting_Wuerth_WA-SMST-3.3mm_H1mm_9774010960.wrl", repo / "new.wrl")
    git("add", "new.wrl")
    passed = git("commit", "-m", "add a new part")
    assert passed.returncode == 0, passed.stdout + passed.stderr


def test_the_gate_answers_from_the_store_while_its_nightly_build_runs(data_dir, tmp_path):
    """A library's cron build keeps the store current; a check-in while it runs answers from what
    the store has committed (the duplicate is found, exit 7), and once the build is done the parts
    it added are found too."""
    import time

    root = tmp_path / "lib"
    for name in PARTS:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(data_dir / "kicad6" / name, root / name)
    store = tmp_path / "lib.shapeidx"
    assert run("build", str(root), "--store", str(store), "--workers", "1", "-q").returncode == 0
    arrived = sorted((data_dir / "kicad6").glob("Connector_*/*.wrl"))[:40]
    assert len(arrived) == 40
    for path in arrived:
        target = root / "new" / path.parent.name / path.name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, target)
    copy = tmp_path / "copy.wrl"
    shutil.copy(root / PARTS[0], copy)
    nightly = subprocess.Popen([sys.executable, "-m", "shapeidx.cli", "build", str(root), "--store", str(store),
                                "--workers", "1", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while "running" not in (store / "build.json").read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        during = run("check-new", str(copy), "--store", str(store), "--format", "json")
        still_running = nightly.poll() is None
    finally:
        out, err = nightly.communicate(timeout=600)
    assert nightly.returncode == 0, err
    assert still_running, "the build ended before the check: give it more files"
    assert during.returncode == 7, during.stderr
    assert json.loads(during.stdout)[0]["duplicates"][0]["relative_path"] == PARTS[0]
    newcomer = tmp_path / "newcomer.wrl"
    shutil.copy(arrived[-1], newcomer)
    after = run("check-new", str(newcomer), "--store", str(store), "--format", "json")
    assert after.returncode == 7, after.stderr
    found = [d["relative_path"] for d in json.loads(after.stdout)[0]["duplicates"]]
    assert f"new/{arrived[-1].parent.name}/{arrived[-1].name}" in found


def test_sheet_draws_each_new_file_its_duplicates_and_look_alikes(library, tmp_path):
    """The reviewer's sheet: one section per file, the files with duplicates first; each
    duplicate marked with its tier, each card a real picture of the stored part (an identical
    copy's picture is its duplicate's), a file that failed named with its reason."""
    import base64
    import html
    import io
    import re

    root, store = library
    copy = tmp_path / "copy.wrl"
    shutil.copy(root / PARTS[0], copy)
    other = tmp_path / "other.wrl"
    shutil.copy(root / PARTS[1], other)
    (tmp_path / "bad.wrl").write_text("junk\n")
    sheet = tmp_path / "review.html"
    done = run("check-new", str(tmp_path / "bad.wrl"), str(other), str(root / PARTS[2]), str(copy), "--store", str(store),
               "--exclude-self", "--sheet", str(sheet))
    assert done.returncode == 1, done.stderr  # an error wins over a duplicate
    text = sheet.read_text()
    sections = re.findall(r'<section class="new" data-status="(\w+)" data-file="([^"]+)"', text)
    assert [s for s, _ in sections] == ["duplicate", "duplicate", "error", "new"]  # a reviewer's order
    assert {html.unescape(f) for _, f in sections} == {str(tmp_path / "bad.wrl"), str(other), str(root / PARTS[2]), str(copy)}
    first = next(part for part in text.split('<section class="new"')[1:] if f'data-file="{copy}"' in part)
    cards = re.findall(r'<article class="hit( dup)?" data-kind="([\w-]+)" data-tier="([\w-]+)" data-path="([^"]+)"', first)
    assert cards[0] == (" dup", "duplicate", "identical", PARTS[0])
    assert all(kind == "look-alike" for _, kind, _, _ in cards[1:]) and len(cards) >= 2
    pictures = re.findall(r'src="data:image/png;base64,([^"]+)"', first)
    from PIL import Image

    images = [Image.open(io.BytesIO(base64.b64decode(p))) for p in pictures]
    assert all(im.size[0] >= 128 for im in images)
    assert pictures[0] == pictures[1]  # the new copy and its identical duplicate: one picture
    assert pictures[0] != pictures[2]  # a look-alike is another part
    assert "not checked" not in text and "bad.wrl" in text and "error:" in text
    blank = run("check-new", str(copy), "--store", str(store), "--sheet", str(tmp_path / "no" / "such.html"))
    assert blank.returncode == 1 and "no folder" in blank.stderr and blank.stderr.count("\n") == 1


@pytest.fixture(scope="module")
def two_exporters(data_dir, tmp_path_factory):
    """xexp-dev: 80 parts as KiCad 6 writes them (tenths of an inch) and as KiCad's 2017 tools
    wrote them (millimetres, other facets), one store of both."""
    store = tmp_path_factory.mktemp("xexp") / "both.shapeidx"
    done = run("build", str(data_dir / "xexp-dev"), "--store", str(store), "--workers", "1", "-q")
    assert done.returncode == 0, done.stderr
    return data_dir / "xexp-dev", store


def test_another_programs_export_in_other_units_is_converted_and_paired_with_its_own_twin_only(two_exporters):
    """One library keeps one unit: a pair within the similar rules at a unit factor is one part
    written by two programs (tier converted), and each such file is paired with its own twin
    (same file name), never with a sibling of the other folder; a remodelled part is no duplicate."""
    root, store = two_exporters
    groups = json.loads(run("duplicates", "--store", str(store), "--format", "json").stdout)
    converted = [p for g in groups for p in g["pairs"] if p["tier"] == "converted"]
    assert len(converted) >= 10  # the C_Rect film capacitors (docs/checkin.md: 24 of the 69 same models)
    for p in converted:
        a, b = p["a"].split("/"), p["b"].split("/")
        assert {a[0], b[0]} == {"kicad6", "kicad2017"} and a[1] == b[1], p
        assert p["unit"] == pytest.approx(1 / 2.54 if a[0] == "kicad2017" else 2.54)  # b over a: mm to 0.1 inch
    # the gate says the same of the new files, one at a time, against the KiCad 6 half
    names = sorted({p["a"].split("/")[1] for p in converted})[:3] + ["DIP-32_W15.24mm.wrl"]
    done = run("check-new", *[str(root / "kicad2017" / n) for n in names], "--store", str(store), "--exclude-self",
               "--format", "json")
    reports = {r["file"].rsplit("/", 1)[1]: r for r in json.loads(done.stdout)}
    assert done.returncode == 7, done.stderr
    for name in names[:3]:
        found = [(d["tier"], d["relative_path"]) for d in reports[name]["duplicates"]]
        assert found == [("converted", f"kicad6/{name}")], found
        assert "another program" in reports[name]["duplicates"][0]["words"]
    assert reports["DIP-32_W15.24mm.wrl"]["status"] == "new"  # remodelled since 2017: 29% more surface


def test_a_library_tree_of_links_knows_its_own_files(data_dir, tmp_path):
    """A store built over a tree of links (--follow-outside-links) holds each file under its
    link's path: checking that link is not news, and checked as new it is not its own duplicate."""
    tree = tmp_path / "links" / "Battery"
    tree.mkdir(parents=True)
    for name in PARTS:
        (tree / name.split("/")[1]).symlink_to(data_dir / "kicad6" / name)
    store = tmp_path / "links.shapeidx"
    done = run("build", str(tree.parent), "--store", str(store), "--workers", "1", "-q", "--follow-outside-links")
    assert done.returncode == 0, done.stderr
    link = tree / PARTS[0].split("/")[1]
    own = run("check-new", str(link), "--store", str(store), "--format", "json")
    assert own.returncode == 0 and json.loads(own.stdout)[0]["status"] == "unchanged", own.stdout
    alone = run("check-new", str(link), "--store", str(store), "--exclude-self", "--format", "json")
    report = json.loads(alone.stdout)[0]
    assert alone.returncode == 0 and report["status"] == "new", report["duplicates"]
    assert report["entry"] == PARTS[0]


def _ci_commands() -> dict:
    """The check-new commands of docs/checkin.md's CI recipes, as written there."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "checkin.md").read_text()
    ci = text.split("## CI", 1)[1].split("\n## ", 1)[0]
    return {"gitlab": re.search(r"- (shapeidx check-new [^\n]*CI_MERGE_REQUEST[^\n]*)", ci).group(1),
            "github": re.search(r"- run: (shapeidx check-new [^\n]*github\.base_ref[^\n]*)", ci).group(1)}


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_the_ci_recipes_commands_run_as_written_on_a_merge_request(library, tmp_path, data_dir):
    """docs/checkin.md's GitLab and GitHub commands, their variables set as those CIs set them,
    run in a clone whose branch adds a duplicate and a new part: status 7, the sheet and the JSON
    the recipes keep as artifacts, naming the duplicate; on a branch adding only a new part, 0."""
    import os

    root, store = library
    env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t", "CI_MERGE_REQUEST_TARGET_BRANCH_NAME": "main"}
    git = lambda *a, cwd: subprocess.run(["git", *a], cwd=cwd, capture_output=True, text=True, env=env, check=True)
    origin, work = tmp_path / "origin.git", tmp_path / "work"
    git("init", "-q", "--bare", "-b", "main", str(origin), cwd=tmp_path)
    git("clone", "-q", str(origin), str(work), cwd=tmp_path)
    (work / "README").write_text("a library\n")
    git("add", "README", cwd=work)
    git("commit", "-qm", "start", cwd=work)
    git("push", "-q", "origin", "HEAD:main", cwd=work)
    git("checkout", "-qb", "new-parts", cwd=work)
    (work / "parts").mkdir()
    shutil.copy(root / PARTS[1], work / "parts" / "dup.wrl")
    shutil.copy(data_dir / "kicad6" / "Mounting_Wuerth" / "Mounting_Wuerth_WA-SMST-3.3mm_H1mm_9774010960.wrl",
                work / "parts" / "new.wrl")
    git("add", "parts", cwd=work)
    git("commit", "-qm", "two parts", cwd=work)
    git("fetch", "-q", "origin", cwd=work)
    commands = _ci_commands()

    def as_ci(command):  # the CI's shell: its variables expanded, the library store where the recipe has it
        command = command.replace("${{ github.base_ref }}", "main").replace("/srv/library.shapeidx", str(store))
        command = command.replace("--store library.shapeidx", f"--store {store}")
        command = command.replace("shapeidx check-new", f"{sys.executable} -m shapeidx.cli check-new", 1)
        return subprocess.run(command, shell=True, cwd=work, capture_output=True, text=True, env=env)

    gitlab = as_ci(commands["gitlab"])
    assert gitlab.returncode == 7, gitlab.stderr
    sheet = (work / "check-new.html").read_text()
    assert 'data-status="duplicate"' in sheet and PARTS[1] in sheet and 'data-status="new"' in sheet
    github = as_ci(commands["github"])
    assert github.returncode == 7, github.stderr
    reports = {os.path.basename(r["file"]): r for r in json.loads((work / "check-new.json").read_text())}
    assert reports["dup.wrl"]["duplicates"][0]["relative_path"] == PARTS[1] and reports["new.wrl"]["status"] == "new"
    git("rm", "-q", "parts/dup.wrl", cwd=work)
    git("commit", "-qm", "keep the library's own", cwd=work)
    assert as_ci(commands["gitlab"]).returncode == 0  # only the new part is left in the range
