"""``craft serve`` reliability probes (issue 12, items 3, 4 and 13).

Out-of-range floats are a 422 (not a 500); image work is bounded before decoding (413/422/503,
fast); an ROI with all-zero grasp scores is never chosen; ``/docs`` loads nothing from a CDN.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from fastapi.testclient import TestClient
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.serve.app import GroundingService, build_service, create_app


class FakeImageEncoder:
    """Embeds every crop as the bundle's 'banana' (no torch): the limits are what is tested."""

    id = "fake-image"
    text_encoder_id = "minilm-l6-v2"

    def __init__(self, vector: npt.NDArray[np.float32]) -> None:
        self.vector = vector
        self.calls = 0

    def embed_images(self, crops: list[Any]) -> npt.NDArray[np.float32]:
        self.calls += 1
        return np.stack([self.vector for _ in crops])


@pytest.fixture(scope="module")
def service(runtime_kbs: RuntimeKBs) -> GroundingService:
    svc = build_service(runtime_kbs.kb)
    b = svc.bundle
    svc.image_encoder = FakeImageEncoder(b.embeddings["object"][b.object_index["banana"]])
    return svc


@pytest.fixture(scope="module")
def client(service: GroundingService) -> Iterator[TestClient]:
    with TestClient(create_app(service), raise_server_exceptions=False) as c:
        yield c


def emb(service: GroundingService, name: str) -> list[float]:
    b = service.bundle
    out: list[float] = b.embeddings["object"][b.object_index[name]].tolist()
    return out


def png(width: int, height: int) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (width, height)).save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode()


# -- item 3: finite values beyond float32 ------------------------------------------------------


@pytest.mark.parametrize("value", [1e39, 1e308, -3.5e38])
def test_huge_embedding_values_are_422_not_500(
    client: TestClient, service: GroundingService, value: float
) -> None:
    vector = emb(service, "hatchet")
    vector[0] = value
    body = {"verb": "cut", "rois": [{"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": vector}]}
    r = client.post("/ground", json=body)
    assert r.status_code == 422, r.text
    assert "image_embedding" in r.text


def test_huge_box_values_are_422(client: TestClient, service: GroundingService) -> None:
    body = {"verb": "cut", "rois": [{"box_xywh": [0, 0, 1e39, 5], "grasp_scores": [0.9],
                                     "image_embedding": emb(service, "hatchet")}]}
    assert client.post("/ground", json=body).status_code == 422


# -- item 4: bounded image work ----------------------------------------------------------------


def test_a_huge_image_is_413_before_decoding(client: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """Judged from the header: decoding pixels (``ImageFile.load``) would fail this test."""
    from PIL import ImageFile

    big = png(6000, 6000)  # ~100 KB of PNG, 36 MP decoded

    def no_decode(self: Any) -> Any:
        raise AssertionError("the server decoded the pixels of an over-sized image")

    monkeypatch.setattr(ImageFile.ImageFile, "load", no_decode)
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": big, "boxes": [{"box_xywh": [0, 0, 10, 10]}]})
    assert r.status_code == 413, r.text
    assert r.json()["detail"]["error"] == "image_too_large"


def test_a_16_bit_image_is_not_clipped_to_white(client: TestClient) -> None:
    """A 16-bit grey PNG (a depth image) converted to RGB clips to white: ``/ground_image``
    embedded that white crop as if it were the scene (``/perceive`` too, before the probe round
    of 2026-12-07). It is a 422 naming the field."""

    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.full((64, 64), 700, np.uint16)).save(out, format="PNG")
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": base64.b64encode(out.getvalue()).decode(),
                                           "boxes": [{"box_xywh": [0, 0, 32, 32], "grasp_scores": [0.5]}]})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["type"] == "image_mode" and "single-channel" in r.json()["detail"][0]["msg"]


def test_an_image_beyond_the_decoders_own_bound_is_413_too(client: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """PIL refuses an image of more than twice its ``MAX_IMAGE_PIXELS`` (about 179 MP) while
    reading the header, before the server's own bound is read: that was a 422 "decompression
    bomb", where a smaller over-sized image is a 413. Both are 413 now."""
    from PIL import Image

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # a 64 x 64 image is then beyond twice the bound
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": png(64, 64),
                                           "boxes": [{"box_xywh": [0, 0, 10, 10], "grasp_scores": [0.5]}]})
    assert r.status_code == 413, r.text
    assert r.json()["detail"]["error"] == "image_too_large"


def test_too_many_boxes_is_422_before_decoding(client: TestClient, service: GroundingService) -> None:
    encoder = service.image_encoder
    before = encoder.calls
    boxes = [{"box_xywh": [0, 0, 64, 64], "grasp_scores": [0.5]}] * (service.max_image_boxes + 1)
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": png(64, 64), "boxes": boxes})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["type"] == "too_many_boxes"
    assert encoder.calls == before


def test_concurrent_decodes_beyond_the_bound_are_503(client: TestClient, service: GroundingService) -> None:
    slot = service.image_slot()
    held = [slot.acquire(blocking=False) for _ in range(service.max_concurrent_images)]
    assert all(held)
    try:
        r = client.post("/ground_image", json={"verb": "cut", "image_b64": png(64, 64),
                                               "boxes": [{"box_xywh": [0, 0, 64, 64], "grasp_scores": [0.5]}]})
        assert r.status_code == 503, r.text
        assert r.headers["retry-after"] == "1"
    finally:
        for _ in held:
            slot.release()
    r = client.post("/ground_image", json={"verb": "cut", "image_b64": png(64, 64),
                                           "boxes": [{"box_xywh": [0, 0, 64, 64], "grasp_scores": [0.5]}]})
    assert r.status_code == 200, r.text


# -- item 13: zero grasp scores, offline docs --------------------------------------------------


def test_an_roi_with_all_zero_grasp_scores_is_never_chosen(client: TestClient, service: GroundingService) -> None:
    rois = [
        {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.0, 0.0], "image_embedding": emb(service, "hatchet"), "label": "hatchet"},
        {"box_xywh": [5, 0, 5, 5], "grasp_scores": [0.2], "image_embedding": emb(service, "banana"), "label": "banana"},
    ]
    r = client.post("/ground", json={"verb": "cut", "rois": rois})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["chosen"] == 1 and [x["index"] for x in d["ranked"]] == [1]
    assert d["excluded"][0]["index"] == 0 and "0.0" in d["excluded"][0]["reason"]


def test_docs_page_loads_nothing_from_the_network(client: TestClient) -> None:
    r = client.get("/docs")
    assert r.status_code == 200
    page = r.text.lower()
    assert "/ground" in page and "<script" not in page and "http" not in page.replace("/openapi.json", "")
    assert client.get("/redoc").status_code == 404
    assert client.get("/openapi.json").status_code == 200


def test_the_grounder_never_chooses_an_roi_whose_grasps_all_score_zero(
    runtime_kbs: RuntimeKBs,
) -> None:
    """Issue 12 item 13 for the Python API (and so ``craft ground`` and the sim), not only serve."""
    from craft_e.runtime.grounding.grounder import ROI, Grounder
    from craft_e.runtime.kb.bundle import load_bundle

    kb = load_bundle(runtime_kbs.kb, check_encoder=False)
    emb = np.ones(kb.manifest.text_encoder.dim, dtype=np.float32)
    rois = [ROI(box_xywh=(0, 0, 10, 10), grasp_scores=[0.0, 0.0], image_embedding=emb),
            ROI(box_xywh=(20, 0, 10, 10), grasp_scores=[0.2], image_embedding=emb)]
    result = Grounder(kb).ground(kb.manifest.verbs[0], rois)
    assert [r.index for r in result.ranked] == [1]
    assert result.excluded[0].index == 0 and "scored 0" in result.excluded[0].reason
