"""shapeidx serve's JSON API, in process (Starlette's test client), on a real store of KiCad parts.

Every request is treated as hostile: unknown ids, path traversal, absolute paths, symbolic
links out of the root, oversized, empty and broken uploads are clear 4xx answers, and the
server goes on answering.
"""

from __future__ import annotations

import io
import os
import tempfile
import warnings

import numpy as np
import pytest
from PIL import Image
from clitools import cli, cli_json
from storetools import FAST_POINTS, small_kicad

pytest.importorskip("starlette")
pytest.importorskip("httpx")
with warnings.catch_warnings():  # Starlette 1.x would rather have httpx's successor; httpx works
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient  # noqa: E402

from shapeidx.distance import compare  # noqa: E402
from shapeidx.distance.metrics import METRICS  # noqa: E402
from shapeidx.search import Searcher  # noqa: E402
from shapeidx.web.app import StoreService, create_app, upload_suffix  # noqa: E402

LIMIT = 3 * 1024 * 1024


@pytest.fixture(scope="module")
def served(data_dir, tmp_path_factory):
    """A store of two KiCad folders plus a broken file and a link to a part outside the root."""
    tmp = tmp_path_factory.mktemp("web")
    tree = small_kicad(data_dir, tmp, ("LED_SMD", "Diode_SMD"))
    (tree / "broken").mkdir()
    (tree / "broken" / "bad.stl").write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\nendsolid\n")
    outside = tmp / "outside"
    outside.mkdir()
    first_led = sorted((tree / "LED_SMD").iterdir())[0]
    (outside / "secret.wrl").write_bytes(first_led.read_bytes())
    (tree / "linked").mkdir()
    os.symlink(outside / "secret.wrl", tree / "linked" / "secret.wrl")
    store = tmp / "s.shapeidx"
    # the link leaves the tree: indexed only when asked, so that the server has such an entry to refuse
    result = cli("build", tree, "--store", store, "--points", FAST_POINTS, "--follow-outside-links")
    assert result.exit_code == 0, result.output
    service = StoreService(store)
    client = TestClient(create_app(service, LIMIT), base_url="http://127.0.0.1:8765")
    yield tree, store, client
    service.close()


def query_by_upload(client, path, name=None, **fields):
    with open(path, "rb") as f:
        return client.post("/api/query", files={"file": (name or path.name, f.read())}, data={k: str(v) for k, v in fields.items()})


class TestAnswers:
    def test_store_facts(self, served):
        _, store, client = served
        info = client.get("/api/store").json()
        assert info["ok"] == 21 and info["failed"] == 1 and info["store"] == str(store.absolute())

    def test_upload_of_a_stored_part_finds_it_first_with_a_picture(self, served):
        tree, _, client = served
        part = sorted((tree / "Diode_SMD").iterdir())[3]
        response = query_by_upload(client, part, top=5, metric="weighted")
        assert response.status_code == 200, response.text
        result = response.json()
        first = result["hits"][0]
        assert first["id"] == f"Diode_SMD/{part.name}" and first["distance"] == 0 and first["words"] == "identical signature"
        assert len(result["hits"]) == 5 and result["query"]["id"].startswith("upload:")
        picture = client.get(first["thumbnail"])
        assert picture.status_code == 200 and picture.headers["content-type"] == "image/png"
        assert Image.open(io.BytesIO(picture.content)).size == (256, 256)
        # the upload is kept: another metric without uploading again
        again = client.get("/api/query", params={"id": result["query"]["id"], "metric": "all", "top": 3}).json()
        assert again["metric"] == "all" and again["hits"][0]["id"] == first["id"]
        assert client.get(result["query"]["thumbnail"]).status_code == 200

    def test_query_by_id_equals_the_command(self, served):
        tree, store, client = served
        entry = "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[2]
        for metric in METRICS:  # every metric the menu offers answers (combined-angle and all-angle were 422)
            got = client.get("/api/query", params={"id": entry, "top": 8, "metric": metric}).json()["hits"]
            expected = cli_json("query", "--id", entry, "--store", store, "-k", "8", "--metric", metric)["hits"]
            assert [(h["id"], h["distance"]) for h in got] == [(h["relative_path"], h["distance"]) for h in expected]

    def test_compare_equals_distance_compare(self, served):
        tree, store, client = served
        a, b = (f"LED_SMD/{p.name}" for p in sorted((tree / "LED_SMD").iterdir())[:2])
        got = client.get("/api/compare", params={"a": a, "b": b}).json()
        with Searcher(store) as searcher:
            sa, sb = searcher.query_of_entry(a).signature, searcher.query_of_entry(b).signature
        assert got["distances"] == compare(sa, sb) and set(got["distances"]) == set(METRICS)
        assert got["labels"]["all"] == "ALL (plain D2)"
        assert np.allclose(got["a"]["histograms"]["in"]["p"], sa.histograms["in"].p, atol=1e-7)

    def test_the_same_part_order_equals_the_command_and_reads_an_upload_s_measures(self, served, tmp_path):
        """``same_part=1`` is ``query --same-part``; an upload keeps its exact measures after its
        part is let go, so a stored part written again in inches, turned, is first at no gap."""
        import trimesh

        from shapeidx.signing import load_part

        tree, store, client = served
        entry = "Diode_SMD/" + sorted(p.name for p in (tree / "Diode_SMD").iterdir())[1]
        got = client.get("/api/query", params={"id": entry, "top": 6, "same_part": 1}).json()
        expected = cli_json("query", "--id", entry, "--store", store, "-k", "6", "--same-part")
        assert got["filters"] == expected["filters"] == ["--same-part"]
        assert [(h["id"], h["distance"], h["shape_gap"]) for h in got["hits"]] == [
            (h["relative_path"], h["distance"], h["shape_gap"]) for h in expected["hits"]]
        plain = client.get("/api/query", params={"id": entry, "top": 6}).json()
        assert all("shape_gap" not in h for h in plain["hits"])
        solid = load_part(tree / entry)
        mesh = trimesh.Trimesh(solid.vertices / 25.4, solid.faces, process=False)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(0.7, (1.0, 1.0, 0.0)))
        mesh.export(tmp_path / "in-inches.stl")
        result = query_by_upload(client, tmp_path / "in-inches.stl", top=4, same_part=1).json()
        assert result["filters"] == ["--same-part"] and result["hits"][0]["id"] == entry
        assert result["hits"][0]["shape_gap"] < 0.01 and all(h["shape_gap"] is not None for h in result["hits"])
        # asked again by its upload id, in the same-part order: the measures are still there
        again = client.get("/api/query", params={"id": result["query"]["id"], "top": 4, "same_part": 1}).json()
        assert [h["shape_gap"] for h in again["hits"]] == [h["shape_gap"] for h in result["hits"]]

    def test_browse_lists_failed_files_with_reasons(self, served):
        _, _, client = served
        failed = client.get("/api/entries", params={"status": "failed"}).json()
        assert failed["total"] == 1 and failed["entries"][0]["id"] == "broken/bad.stl" and failed["entries"][0]["reason"]
        some = client.get("/api/entries", params={"q": "led_smd", "limit": 4, "offset": 2}).json()
        assert some["total"] == 10 and len(some["entries"]) == 4 and all(e["id"].startswith("LED_SMD/") for e in some["entries"])

    def test_the_page_and_its_files(self, served):
        _, _, client = served
        page = client.get("/")
        assert page.status_code == 200 and "/static/app.js" in page.text
        assert "default-src 'self'" in page.headers["content-security-policy"]
        assert client.get("/static/app.js").status_code == 200


class TestHostileRequests:
    @pytest.mark.parametrize("bad", ["../../../../etc/passwd", "/etc/passwd", "LED_SMD/../../s.shapeidx/main.h5", "LED_SMD", "", "nul\x00l"])
    def test_ids_that_are_not_entries(self, served, bad):
        _, _, client = served
        for url in ("/api/thumbnail", "/api/query", "/api/entry"):
            response = client.get(url, params={"id": bad})
            assert response.status_code in (400, 404), (url, bad, response.status_code)
            assert "error" in response.json()

    def test_a_link_out_of_the_root_is_refused(self, served):
        _, _, client = served
        response = client.get("/api/thumbnail", params={"id": "linked/secret.wrl"})
        assert response.status_code == 403 and "outside the store's root" in response.json()["error"]

    def test_failed_entry_and_bad_parameters(self, served):
        _, _, client = served
        assert client.get("/api/query", params={"id": "broken/bad.stl"}).status_code == 409
        entry = client.get("/api/entries", params={"status": "ok", "limit": 1}).json()["entries"][0]["id"]
        for params in ({"metric": "euclid"}, {"top": "0"}, {"top": "ten"}, {"top": "999999"}, {"same_part": "2"},
                       {"uses": "1", "same_part": "1"}):
            response = client.get("/api/query", params={"id": entry, **params})
            assert response.status_code == 400, params
        assert client.get("/api/nothing").status_code == 404
        assert client.get("/api/query", params={"id": "upload:0123"}).status_code == 404

    def test_bad_uploads_are_4xx_with_the_reason_and_leave_nothing_behind(self, served, tmp_path, monkeypatch):
        tree, _, client = served
        monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
        garbage = client.post("/api/query", files={"file": ("bracket.stl", b"\x00garbage" * 40)})
        assert garbage.status_code == 422 and garbage.json()["error"].startswith("bracket.stl: ")
        empty = client.post("/api/query", files={"file": ("empty.obj", b"")})
        assert empty.status_code == 422 and "empty" in empty.json()["error"]
        no_file = client.post("/api/query", data={"top": "3"}, files={"other": ("x.stl", b"x")})
        assert no_file.status_code == 400 and "'file'" in no_file.json()["error"]
        not_multipart = client.post("/api/query", content=b"{}", headers={"content-type": "application/json"})
        assert not_multipart.status_code == 415
        too_big = client.post("/api/query", files={"file": ("big.stl", b"0" * (LIMIT + 1))})
        assert too_big.status_code == 413
        assert list(tmp_path.iterdir()) == []  # every temporary upload was removed
        # and the server still answers
        part = sorted((tree / "LED_SMD").iterdir())[0]
        assert query_by_upload(client, part, top=1).status_code == 200

    def test_a_part_without_a_known_suffix_is_read_by_its_content(self, served):
        tree, _, client = served
        part = sorted((tree / "LED_SMD").iterdir())[4]
        response = query_by_upload(client, part, name="mystery.bin", top=1)
        assert response.status_code == 200, response.text
        assert response.json()["hits"][0]["id"] == f"LED_SMD/{part.name}"

    def test_upload_suffix(self):
        assert upload_suffix("Part.WRL.gz") == ".wrl.gz"
        assert upload_suffix("../../../etc/evil.stl") == ".stl"
        assert upload_suffix("C:\\parts\\a.OBJ") == ".obj"
        assert upload_suffix("noext") == ".part" and upload_suffix("x.exe") == ".part"
