"""The ``POST /ground`` example of docs/serving.md, answered by the shipped default bundle.

Runs the server's app in-process (no port), with the two ROIs' image embeddings set to the
bundle's own text embeddings of "knife" and "cup" (a stand-in for an image encoder's output:
ROI 0 looks exactly like a knife, ROI 1 like a cup), and prints the answer, so the example in the
docs is this command's output: ``.venv/bin/python examples/serving/ground_request.py``.
"""

from __future__ import annotations

import json

from fastapi.testclient import TestClient

from craft_e.paths import KB_DIR
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.serve.app import create_app


def main() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default")
    objects = bundle.embeddings["object"]  # [O, 384] in the bundle's text space

    def looks_like(name: str) -> list[float]:
        return [round(float(v), 6) for v in objects[bundle.object_index[name]]]

    request = {
        "verb": "cut",
        "rois": [
            {"box_xywh": [120, 40, 80, 60], "grasp_scores": [0.3, 0.9], "image_embedding": looks_like("knife"),
             "label": "roi-0"},
            {"box_xywh": [260, 50, 70, 90], "grasp_scores": [0.8], "image_embedding": looks_like("cup")},
        ],
        "options": {"alpha": 1.0, "beta": 1.0, "gamma": 1.0, "top_k": 3},
    }
    with TestClient(create_app(bundle)) as client:
        answer = client.post("/ground", json=request)
    answer.raise_for_status()
    print(json.dumps(answer.json(), indent=1))


if __name__ == "__main__":
    main()
