"""``craft serve``: the HTTP API over the grounder, good and bad requests (FastAPI TestClient).

The answers must be exactly what ``Grounder.ground`` gives in-process; every malformed request
gets a 4xx that says why (never a 500), and the bundle is verified before anything is served.
One test runs the real ``craft serve`` command (uvicorn on a local port) end to end.
"""

from __future__ import annotations

import base64
import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from runtime_fixtures import RuntimeKBs, conse_fixture, runtime_kbs_fixture, shared_image  # noqa: F401
from typer.testing import CliRunner

from craft_e.runtime.grounding.grounder import ROI, Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.serve.app import GroundingService, ServeError, build_service, create_app


@pytest.fixture(scope="module")
def service(runtime_kbs: RuntimeKBs) -> GroundingService:
    return build_service(runtime_kbs.kb)


@pytest.fixture(scope="module")
def client(service: GroundingService) -> Iterator[TestClient]:
    with TestClient(create_app(service)) as c:
        yield c


def emb(service: GroundingService, name: str) -> list[float]:
    """The bundle's text embedding of an object: an ROI that "looks exactly like" it."""
    b = service.bundle
    out: list[float] = b.embeddings["object"][b.object_index[name]].tolist()
    return out


def scene(service: GroundingService) -> list[dict[str, Any]]:
    return [
        {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": emb(service, "banana"), "label": "banana"},
        {"box_xywh": [5, 0, 5, 5], "grasp_scores": [], "image_embedding": emb(service, "cleaver"), "label": "cleaver"},
        {"box_xywh": [0, 5, 5, 5], "grasp_scores": [0.3, 0.9, 0.6], "image_embedding": emb(service, "hatchet"),
         "label": "hatchet"},
        {"box_xywh": [5, 5, 5, 5], "grasp_scores": [0.9], "image_embedding": None, "label": "unseen"},
    ]


def as_rois(items: list[dict[str, Any]]) -> list[ROI]:
    return [ROI(tuple(r["box_xywh"]), r["grasp_scores"],
                image_embedding=None if r["image_embedding"] is None else np.asarray(r["image_embedding"], np.float32),
                label=r["label"]) for r in items]


# -- good requests ---------------------------------------------------------------------------


def test_healthz_and_verbs(client: TestClient, runtime_kbs: RuntimeKBs) -> None:
    m = load_bundle(runtime_kbs.kb).manifest
    h = client.get("/healthz").json()
    assert h["status"] == "ok" and h["kb"] == m.kb_name and h["version"] == m.kb_version
    assert h["content_sha256"] == m.content_sha256 and h["dim"] == 384 and h["image_encoder"] is None
    v = client.get("/verbs").json()
    assert v["verbs"] == list(m.verbs) and v["open_vocab"] is False


def test_ground_matches_the_in_process_grounder(client: TestClient, service: GroundingService) -> None:
    items = scene(service)
    r = client.post("/ground", json={"verb": "cut", "rois": items})
    assert r.status_code == 200, r.text
    data = r.json()
    want = Grounder(service.bundle).ground("cut", as_rois(items)).to_dict()
    assert [x["index"] for x in data["ranked"]] == [x["index"] for x in want["ranked"]] == [2, 0]
    for got, exp in zip(data["ranked"], want["ranked"], strict=True):
        for key in ("e_grasp", "e_aff", "e_align", "total"):
            assert got[key] == pytest.approx(exp[key], abs=1e-6)
    assert data["chosen"] == 2
    assert data["chosen_grasp"] == {"roi": 2, "grasp_index": 1, "grasp_score": 0.9}
    best = data["ranked"][0]
    assert best["hypotheses"][0]["object"] == "hatchet" and best["label"] == "hatchet"
    assert {p["property"] for p in best["paths"]} >= {"sharp edge", "has a blade"}
    assert all(len(p["records"]) == 2 and all(len(k) == 64 for k in p["records"]) for p in best["paths"])
    reasons = {e["label"]: e["reason"] for e in data["excluded"]}
    assert set(reasons) == {"cleaver", "unseen"} and "no grasp" in reasons["cleaver"]
    assert data["kb_content_sha256"] == service.bundle.manifest.content_sha256
    assert data["ranked_total"] == 2


def test_options_weights_form_and_top_k(client: TestClient, service: GroundingService, runtime_kbs: RuntimeKBs) -> None:
    items = scene(service)
    base = client.post("/ground", json={"verb": "cut", "rois": items}).json()["ranked"]
    w = client.post("/ground", json={"verb": "cut", "rois": items,
                                     "options": {"alpha": 2, "beta": 0.5, "gamma": 0}}).json()
    assert w["settings"]["alpha"] == 2 and w["settings"]["gamma"] == 0
    by_index = {x["index"]: x for x in base}
    for x in w["ranked"]:
        b = by_index[x["index"]]
        assert x["total"] == pytest.approx(2 * b["e_grasp"] + 0.5 * b["e_aff"], abs=1e-5)
    again = client.post("/ground", json={"verb": "cut", "rois": items}).json()
    assert again["settings"]["alpha"] == 1.0 and again["ranked"] == base  # no leak between requests

    norm = client.post("/ground", json={"verb": "cut", "rois": items,
                                        "options": {"energy_form": "normalized-product"}}).json()
    want = Grounder(load_bundle(runtime_kbs.kb), GroundingSettings(energy_form="normalized-product")).ground("cut", as_rois(items))
    assert norm["settings"]["energy_form"] == "normalized-product"
    assert [x["e_aff"] for x in norm["ranked"]] == pytest.approx([r.e_aff for r in want.ranked], abs=1e-6)

    top = client.post("/ground", json={"verb": "cut", "rois": items, "options": {"top_k": 1}}).json()
    assert len(top["ranked"]) == 1 and top["ranked_total"] == 2 and top["chosen"] == 2


def test_openapi_documents_the_request_bodies(client: TestClient) -> None:
    doc = client.get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    assert {"GroundRequest", "RoiIn", "GroundOptions", "GroundImageRequest"} <= set(schemas)
    body = doc["paths"]["/ground"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert body == {"$ref": "#/components/schemas/GroundRequest"}


# -- bad requests ----------------------------------------------------------------------------


def test_unknown_verb_is_404_with_close_matches(client: TestClient, service: GroundingService) -> None:
    r = client.post("/ground", json={"verb": "cutt", "rois": scene(service)})
    assert r.status_code == 404
    d = r.json()["detail"]
    assert d["error"] == "unknown_verb" and d["close_matches"] == ["cut"] and "cutt" in d["message"]


def test_wrong_embedding_dimension_names_the_expected_dim(client: TestClient, service: GroundingService) -> None:
    items = scene(service)
    items[2]["image_embedding"] = [0.1] * 512
    r = client.post("/ground", json={"verb": "cut", "rois": items})
    assert r.status_code == 422
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "rois", 2, "image_embedding"] and err["type"] == "embedding_dimension"
    assert "expected 384" in err["msg"] and "got 512" in err["msg"]
    items[2]["image_embedding"] = [0.0] * 384
    r = client.post("/ground", json={"verb": "cut", "rois": items})
    assert r.status_code == 422 and r.json()["detail"][0]["type"] == "embedding_zero"


@pytest.mark.parametrize(("body", "loc", "kind"), [
    ({"rois": []}, ["body", "verb"], "missing"),
    ({"verb": "cut", "rois": []}, ["body", "rois"], "too_short"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, -1, 5]}]}, ["body", "rois", 0, "box_xywh"], "value_error"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, 5]}]}, ["body", "rois", 0, "box_xywh"], "missing"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5], "grasp_scores": [1.5]}]},
     ["body", "rois", 0, "grasp_scores"], "value_error"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5], "colour": "red"}]},
     ["body", "rois", 0, "colour"], "extra_forbidden"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5]}], "options": {"alpha": -1}},
     ["body", "options", "alpha"], "greater_than_equal"),
    ({"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5]}], "options": {"energy_form": "product"}},
     ["body", "options", "energy_form"], "literal_error"),
    ({"verb": "x" * 101, "rois": [{"box_xywh": [0, 0, 5, 5]}]}, ["body", "verb"], "string_too_long"),
    ({"verb": "  ", "rois": [{"box_xywh": [0, 0, 5, 5]}]}, ["body", "verb"], "value_error"),
])
def test_schema_errors_are_422_with_location(client: TestClient, body: dict[str, Any], loc: list[Any], kind: str) -> None:
    r = client.post("/ground", json=body)
    assert r.status_code == 422, r.text
    errors = r.json()["detail"]
    assert any(e["loc"][: len(loc)] == loc and e["type"] == kind for e in errors), errors
    assert all(set(e) == {"loc", "msg", "type"} for e in errors)  # the input is never echoed


@pytest.mark.parametrize("raw", [b'{"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5], "grasp_scores": [NaN]}]}',
                                 b'{"verb": "cut", "rois": [{"box_xywh": [0, 0, Infinity, 5]}]}',
                                 b'{"verb": "cut", "rois": [', b"not json"])
def test_non_finite_numbers_and_broken_json_are_422(client: TestClient, raw: bytes) -> None:
    r = client.post("/ground", content=raw, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["type"] in ("finite_number", "json_invalid")


def test_too_many_rois_names_the_bound(service: GroundingService) -> None:
    small = build_service(service.bundle, max_rois=3)
    with TestClient(create_app(small)) as c:
        r = c.post("/ground", json={"verb": "cut", "rois": scene(service)})
        assert r.status_code == 422
        (err,) = r.json()["detail"]
        assert err["type"] == "too_many_rois" and "at most 3" in err["msg"] and "4 regions" in err["msg"]
        assert c.post("/ground", json={"verb": "cut", "rois": scene(service)[:3]}).status_code == 200


def test_oversized_bodies_are_413_declared_or_chunked(service: GroundingService) -> None:
    body = json.dumps({"verb": "cut", "rois": scene(service)}).encode()
    small = json.dumps({"verb": "cut", "rois": [{"box_xywh": [0, 0, 1, 1], "grasp_scores": [0.5],
                                                 "image_embedding": emb(service, "cup")}]}).encode()
    limit = (len(body) + len(small)) // 2
    headers = {"content-type": "application/json"}
    with TestClient(create_app(service, max_body_bytes=limit)) as c:
        r = c.post("/ground", content=body, headers=headers)
        assert r.status_code == 413 and r.json()["detail"]["limit_bytes"] == limit
        chunks = iter([body[:3000], body[3000:]])  # no Content-Length: Transfer-Encoding chunked
        r = c.post("/ground", content=chunks, headers=headers)
        assert r.status_code == 413
        r = c.post("/ground", content=iter([small[:100], small[100:]]), headers=headers)
        assert r.status_code == 200, r.text  # a chunked body under the bound is replayed whole


# -- startup ---------------------------------------------------------------------------------


def test_startup_refuses_a_tampered_bundle_or_another_space(runtime_kbs: RuntimeKBs, tmp_path: Path, conse: Any) -> None:
    import shutil

    bad = tmp_path / "kb"
    shutil.copytree(runtime_kbs.kb, bad)
    (bad / "graph.json").write_bytes((bad / "graph.json").read_bytes() + b" ")
    with pytest.raises(BundleError, match=r"graph\.json"):
        create_app(bad)
    with pytest.raises(BundleError, match="text encoder"):
        create_app(runtime_kbs.other_encoder, image_encoder=conse)
    with pytest.raises(ServeError, match="max_rois"):
        build_service(runtime_kbs.kb, max_rois=0)


def test_open_vocab_server_grounds_unknown_verbs(runtime_kbs: RuntimeKBs) -> None:
    svc = build_service(runtime_kbs.kb, settings=GroundingSettings(open_vocab=True))
    with TestClient(create_app(svc)) as c:
        r = c.post("/ground", json={"verb": "chop", "rois": scene(svc)})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["open_vocab_used"] is True and d["nearest_verbs"]


# -- server-side image embedding -------------------------------------------------------------


def two_photo_png(left: str, right: str, size: int = 224) -> bytes:
    from PIL import Image

    canvas = Image.new("RGB", (2 * size, size))
    for i, name in enumerate((left, right)):
        with Image.open(shared_image(name)) as img:
            canvas.paste(img.convert("RGB").resize((size, size)), (i * size, 0))
    buf = io.BytesIO()
    canvas.save(buf, format="PNG")
    return buf.getvalue()


def test_ground_image_embeds_crops_server_side(runtime_kbs: RuntimeKBs, conse: Any) -> None:
    from craft_e.runtime.encoders.image import crop_box, load_image

    svc = build_service(runtime_kbs.kb, image_encoder=conse)
    png = two_photo_png("banana", "hatchet")
    boxes: list[dict[str, Any]] = [{"box_xywh": [0, 0, 224, 224], "grasp_scores": [0.8], "label": "left"},
             {"box_xywh": [224, 0, 224, 224], "grasp_scores": [0.8], "label": "right"}]
    with TestClient(create_app(svc)) as c:
        assert c.get("/healthz").json()["image_encoder"] == conse.id
        r = c.post("/ground_image", json={"verb": "cut", "image_b64": base64.b64encode(png).decode(), "boxes": boxes})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["image"]["width"] == 448 and d["image"]["height"] == 224 and d["image"]["encoder"] == conse.id
        assert d["ranked"][0]["label"] == "right" and d["ranked"][0]["hypotheses"][0]["object"] == "hatchet"
        # the same as embedding the crops in-process
        path = Path(os.environ.get("TMPDIR", "/tmp")) / f"serve-test-{os.getpid()}.png"
        path.write_bytes(png)
        try:
            rgb = load_image(str(path))
        finally:
            path.unlink()
        e = conse.embed_images([crop_box(rgb, b["box_xywh"]) for b in boxes])
        want = Grounder(svc.bundle).ground("cut", [ROI(tuple(b["box_xywh"]), [0.8], image_embedding=e[i])
                                                   for i, b in enumerate(boxes)])
        assert [x["total"] for x in d["ranked"]] == pytest.approx([x.total for x in want.ranked], abs=1e-5)

        bad = [("not base64!", "image_base64"), (base64.b64encode(b"GIF89a....").decode(), "image_decode")]
        for payload, kind in bad:
            r = c.post("/ground_image", json={"verb": "cut", "image_b64": payload, "boxes": boxes})
            assert r.status_code == 422 and r.json()["detail"][0]["type"] == kind, r.text
        from PIL import Image

        gif = io.BytesIO()
        Image.new("RGB", (8, 8)).save(gif, format="GIF")
        r = c.post("/ground_image", json={"verb": "cut", "image_b64": base64.b64encode(gif.getvalue()).decode(),
                                          "boxes": boxes})
        assert r.status_code == 422 and "PNG or JPEG" in r.json()["detail"][0]["msg"]
        outside = [{"box_xywh": [1000, 1000, 10, 10], "grasp_scores": [0.5]}]
        r = c.post("/ground_image", json={"verb": "cut", "image_b64": base64.b64encode(png).decode(), "boxes": outside})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "boxes", 0, "box_xywh"]
        assert not d["notes"]  # both boxes lie inside the image
        half = [{"box_xywh": [400, 100, 100, 100], "grasp_scores": [0.5]}]
        r = c.post("/ground_image", json={"verb": "cut", "image_b64": base64.b64encode(png).decode(), "boxes": half})
        assert r.status_code == 200 and r.json()["notes"] == [
            "box 0 [400.0, 100.0, 100.0, 100.0] reaches past the 448x224 image: only the part inside was embedded"]


def test_ground_image_without_encoder_is_503(client: TestClient) -> None:
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": "aGVsbG8=",
                                           "boxes": [{"box_xywh": [0, 0, 1, 1]}]})
    assert r.status_code == 503 and r.json()["detail"]["error"] == "image_encoder_disabled"


# -- the command -----------------------------------------------------------------------------


def test_cli_refuses_a_missing_bundle_with_exit_2(tmp_path: Path) -> None:
    from craft_e.runtime.cli.main import app

    r = CliRunner().invoke(app, ["serve", "--kb", str(tmp_path / "nope"), "--image-encoder", "none", "--port", "0"])
    assert r.exit_code == 2 and "not a bundle folder" in r.output
    r = CliRunner().invoke(app, ["serve", "--kb", str(tmp_path), "--image-encoder", "clip"])
    assert r.exit_code == 2 and "--image-encoder" in r.output


def test_cli_port_0_does_not_print_port_0(runtime_kbs: RuntimeKBs, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--port 0`` lets the OS pick the port when uvicorn binds; the start-up line said ``:0``."""
    import uvicorn

    from craft_e.runtime.cli.main import app

    ran: dict[str, Any] = {}
    monkeypatch.setattr(uvicorn, "run", lambda *a, **k: ran.update(k))
    r = CliRunner().invoke(app, ["serve", "--kb", str(runtime_kbs.kb), "--image-encoder", "none", "--port", "0"])
    assert r.exit_code == 0, r.output
    said = " ".join(r.output.split())
    assert ran["port"] == 0 and ":0" not in said and "a free port the OS picks" in said
    with socket.socket() as probe:  # a port free now (the command checks it can listen there)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    r = CliRunner().invoke(app, ["serve", "--kb", str(runtime_kbs.kb), "--image-encoder", "none", "--port", str(port)])
    assert r.exit_code == 0 and f"on http://127.0.0.1:{port}" in " ".join(r.output.split()), r.output


def test_cli_names_a_busy_port_and_a_bad_host_before_loading(tmp_path: Path) -> None:
    import socket

    from craft_e.runtime.cli.main import app

    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        r = CliRunner().invoke(app, ["serve", "--kb", str(tmp_path / "nope"), "--port", str(port)])
        assert r.exit_code == 2 and f"cannot listen on 127.0.0.1:{port}" in " ".join(r.output.split())
    r = CliRunner().invoke(app, ["serve", "--kb", str(tmp_path / "nope"), "--host", "999.1.1.1"])
    assert r.exit_code == 2 and "--host '999.1.1.1'" in r.output


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def test_craft_serve_answers_over_http(runtime_kbs: RuntimeKBs, service: GroundingService) -> None:
    """The real command: uvicorn on 127.0.0.1, healthz, one grounding, clean SIGTERM shutdown."""
    port = _free_port()
    code = "from craft_e.runtime.cli.main import app; app(prog_name='craft')"
    proc = subprocess.Popen([sys.executable, "-c", code, "serve", "--kb", str(runtime_kbs.kb), "--port", str(port),
                             "--image-encoder", "none", "--log-level", "warning"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, proc.stdout.read().decode() if proc.stdout else ""
            try:
                health = httpx.get(f"{base}/healthz", timeout=1).json()
                break
            except httpx.HTTPError:
                assert time.monotonic() < deadline, "craft serve did not come up"
                time.sleep(0.1)
        assert health["content_sha256"] == service.bundle.manifest.content_sha256
        r = httpx.post(f"{base}/ground", json={"verb": "cut", "rois": scene(service)}, timeout=10)
        assert r.status_code == 200 and r.json()["chosen"] == 2
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
    # uvicorn shuts down gracefully, then re-raises the captured SIGTERM (exit status -15)
    assert proc.returncode in (0, -signal.SIGTERM), out.decode()
