"""``craft serve``: run the grounding HTTP API (``runtime/serve/app.py``) with uvicorn, one process.

The bundle is loaded and verified, and the grounders built, *before* the port is bound: a
refused bundle exits 2 with the loader's message and never answers a request. Binds 127.0.0.1
by default: the API has no authentication, so exposing it is an explicit choice (``--host
0.0.0.0``) for a trusted robot network.

Exit codes: 0 clean shutdown; 2 bad input (bundle refused, encoder mismatch, bad option).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from .common import err, fail, grounding_settings
from .episodes import GripperOpt


def listen_problem(host: str, port: int) -> str | None:
    """Why uvicorn could not listen on ``host:port`` (None if it can), tried before the bundle
    loads, so a busy port or a mistyped host is a one-line error naming the fix, not a server
    log line after seconds of loading."""
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        return f"--host {host!r}: not an address or a name this machine resolves ({exc.strerror})"
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            probe.bind(address)
        except OSError as exc:
            return (f"cannot listen on {host}:{port} ({exc.strerror}); choose another --port "
                    "(or --port 0 for any free one) or stop what holds it")
    return None


def serve_cmd(
    kb: Annotated[Path, typer.Option(help="Bundle folder (or signed .craft file with --trusted-key).")],
    host: Annotated[str, typer.Option(help="Interface to bind (no auth: keep it local or on a trusted network).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port (0: any free port).")] = 8080,
    image_encoder: Annotated[str, typer.Option(help="conse (enables POST /ground_image and POST /perceive) | none.")] = "conse",
    threads: Annotated[int, typer.Option(min=1, help="Torch threads of the image encoder.")] = 1,
    max_rois: Annotated[int, typer.Option(min=1, help="Most ROIs accepted in one request (422 above).")] = 64,
    max_body_bytes: Annotated[int, typer.Option(min=1024, help="Largest /ground body in bytes (413 above).")] = 2 * 1024 * 1024,
    temperature: Annotated[float | None, typer.Option(help="Softmax temperature of p(o|r) (default: 0.1, fixed a priori; grounding/settings.py).")] = None,
    open_vocab: Annotated[bool, typer.Option(help="Ground verbs the KB lacks via similar KB verbs (else 404).")] = False,
    trusted_key: Annotated[list[Path] | None, typer.Option("--trusted-key", help="Signer key for a .craft package.")] = None,
    gripper: GripperOpt = "panda",
    log_level: Annotated[str, typer.Option(help="uvicorn log level: critical | error | warning | info | debug.")] = "info",
    access_log: Annotated[bool, typer.Option(help="Log every request (costs throughput).")] = False,
) -> None:
    """Serve POST /ground, POST /ground_image, POST /perceive, GET /healthz and GET /verbs over HTTP."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see cli/main.py: tiny matmuls, busy cores
    import uvicorn

    from ..encoders import EncoderError
    from ..kb.bundle import BundleError
    from ..serve.app import ServeError, create_app, load_image_encoder, robot_encoder

    if image_encoder not in ("conse", "none"):
        fail(f"--image-encoder {image_encoder!r}: use conse or none")
    from ..sim.hands import HANDS

    if gripper not in HANDS:
        fail(f"--gripper {gripper!r}: use {' or '.join(HANDS)} (the hand POST /perceive checks grasps against)")
    settings = grounding_settings(temperature=temperature, open_vocab=open_vocab)
    problem = listen_problem(host, port)
    if problem is not None:
        fail(problem)
    if log_level not in ("critical", "error", "warning", "info", "debug"):
        fail(f"--log-level {log_level!r}: use critical, error, warning, info or debug")
    try:
        encoder = load_image_encoder("conse" if image_encoder == "conse" else "none", threads=threads,
                                     sense_weight=settings.class_senses, temperature=settings.conse_temperature)
        # POST /perceive: the robot's encoder (sim_eval.default_encoder: whole square crops), the
        # same classifier and class names as /ground_image's, which crops caller boxes its own way
        frame_encoder = robot_encoder(encoder)
        app = create_app(kb, image_encoder=encoder, max_rois=max_rois, settings=settings,
                         trusted_keys=[str(k) for k in trusted_key] if trusted_key else None,
                         max_body_bytes=max_body_bytes, frame_encoder=frame_encoder, gripper=gripper)
    except (BundleError, ServeError, EncoderError) as exc:
        fail(str(exc))
    health = app.state.service.health()
    # --port 0 asks the OS for a free port when uvicorn binds: only uvicorn's next line knows it
    where = f"http://{host}:{port}" if port else f"{host}, on a free port the OS picks (uvicorn's next line names it)"
    err.print(f"serving {health['kb']}@{health['version']} (content sha256 {health['content_sha256'][:16]}..., "
               f"{health['verbs']} verbs, dim {health['dim']}, image encoder {health['image_encoder'] or 'none'}) "
               f"on {where}", highlight=False, soft_wrap=True)
    uvicorn.run(app, host=host, port=port, log_level=log_level, access_log=access_log, workers=1)

