"""Local fake servers for contract tests: real HTTP on 127.0.0.1, scripted answers.

Tests exercise the real httpx code paths (status codes, headers, cut connections, timeouts)
without any remote API. A ``FakeServer`` runs ``http.server.ThreadingHTTPServer`` in a daemon
thread, records every request it receives, and answers each with the next scripted ``Reply`` /
``CutBody`` (or with a ``responder`` function once the script is used up).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import parse_qsl, urlsplit


@dataclass(frozen=True)
class Received:
    """One request as the server saw it."""

    method: str
    path: str  # with the query string
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)

    @property
    def route(self) -> str:
        return urlsplit(self.path).path

    @property
    def query(self) -> dict[str, str]:
        return dict(parse_qsl(urlsplit(self.path).query, keep_blank_values=True))


@dataclass(frozen=True)
class Reply:
    """A whole HTTP answer; ``delay_s`` waits before sending (to trigger client timeouts)."""

    status: int = 200
    body: Any = b""
    headers: dict[str, str] = field(default_factory=dict)
    delay_s: float = 0.0

    def payload(self) -> bytes:
        if isinstance(self.body, bytes):
            return self.body
        if isinstance(self.body, str):
            return self.body.encode()
        return json.dumps(self.body).encode()


@dataclass(frozen=True)
class CutBody:
    """Headers promising ``declared_length`` bytes, then only ``sent``, then a closed socket."""

    sent: bytes = b'{"choices": [{"mess'
    declared_length: int = 4096
    status: int = 200


Action = Reply | CutBody
Responder = Callable[[Received], Action]


def _not_scripted(request: Received) -> Action:
    return Reply(500, {"error": {"message": f"fake server: nothing scripted for {request.path}"}})


class FakeServer:
    """A threaded HTTP server on an ephemeral port; use as a context manager."""

    def __init__(self, script: Iterable[Action] = (), responder: Responder | None = None) -> None:
        self.script: list[Action] = list(script)
        self.responder = responder or _not_scripted
        self.received: list[Received] = []
        self._lock = threading.Lock()
        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), self._handler_class())
        self._httpd.daemon_threads = True
        self._httpd.block_on_close = False
        # A short poll interval: shutdown() waits for the next poll, 0.5 s by default.
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.01}, daemon=True
        )

    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        return f"http://{host!s}:{port}"

    def __enter__(self) -> FakeServer:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def next_action(self, request: Received) -> Action:
        with self._lock:
            self.received.append(request)
            if self.script:
                return self.script.pop(0)
        return self.responder(request)

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, format: str, *args: Any) -> None:  # keep test output quiet
                return

            def do_GET(self) -> None:
                self._serve()

            def do_POST(self) -> None:
                self._serve()

            def _serve(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(length) if length else b""
                request = Received(self.command, self.path, dict(self.headers.items()), body)
                action = server.next_action(request)
                if isinstance(action, CutBody):
                    self._cut(action)
                else:
                    self._reply(action)

            def _reply(self, reply: Reply) -> None:
                if reply.delay_s:
                    time.sleep(reply.delay_s)
                data = reply.payload()
                try:
                    self.send_response(reply.status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
                    for name, value in reply.headers.items():
                        self.send_header(name, value)
                    self.end_headers()
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError):  # the client gave up (timeout)
                    self.close_connection = True

            def _cut(self, cut: CutBody) -> None:
                self.send_response(cut.status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(cut.declared_length))
                self.end_headers()
                self.wfile.write(cut.sent)
                self.wfile.flush()
                self.close_connection = True

        return Handler


# -- wire-format helpers -----------------------------------------------------------------------


def openai_reply(content: str, finish_reason: str = "stop") -> Reply:
    """A chat-completions success answer carrying ``content`` as the assistant message."""
    return Reply(200, {
        "id": "chatcmpl-test", "object": "chat.completion", "model": "test-model",
        "choices": [{"index": 0, "finish_reason": finish_reason,
                     "message": {"role": "assistant", "content": content}}],
        "usage": {"prompt_tokens": 10, "completion_tokens": 10, "total_tokens": 20},
    })


def gemini_reply(content: str, finish_reason: str = "STOP") -> Reply:
    """A generateContent success answer carrying ``content`` as the model's text part."""
    return Reply(200, {
        "candidates": [{"content": {"role": "model", "parts": [{"text": content}]},
                        "finishReason": finish_reason, "index": 0}],
        "usageMetadata": {"promptTokenCount": 10, "candidatesTokenCount": 10},
    })


# -- ConceptNet ------------------------------------------------------------------------------


class ConceptNetPages:
    """Serves the recorded ``/c/en/spoon`` pages and a ``/query`` computed from their edges.

    The recording holds the first page (top level) and ``index_1``..``index_N`` for the next
    offsets. Offsets past the recording get an empty last page without ``nextPage``, as the
    real API ends a listing. ``/query`` filters every recorded edge by ``start``/``end``/
    ``node``/``rel`` (URI prefix match, like ConceptNet) and paginates with offset/limit.
    """

    def __init__(self, path: Path) -> None:
        data = json.loads(path.read_text(encoding="utf-8"))
        self.term: str = data["@id"]
        first = {k: v for k, v in data.items() if not k.startswith("index_")}
        pages = [first] + [data[f"index_{i}"] for i in range(1, int(data["index_length"]) + 1)]
        self.pages = {self._offset(p["view"]["@id"]): p for p in pages}
        self.page_size = len(first["edges"])
        self.edges = [e for p in pages for e in p["edges"]]

    @staticmethod
    def _offset(ref: str) -> int:
        return int(dict(parse_qsl(urlsplit(ref).query)).get("offset", 0))

    def __call__(self, request: Received) -> Action:
        if request.route == self.term:
            return self._term_page(int(request.query.get("offset", 0)))
        if request.route == "/query":
            return self._query(request.query)
        return Reply(404, {"error": "not found", "details": request.path})

    def _term_page(self, offset: int) -> Reply:
        page = self.pages.get(offset)
        if page is None:
            return Reply(200, {"@id": self.term, "edges": [],
                               "view": {"@id": f"{self.term}?offset={offset}", "paginatedProperty": "edges"}})
        return Reply(200, page)

    def _query(self, query: dict[str, str]) -> Reply:
        def matches(node: Any, uri: str) -> bool:
            at = node.get("@id", "") if isinstance(node, dict) else ""
            return bool(at == uri or at.startswith(uri + "/"))

        edges = [
            e for e in self.edges
            if ("start" not in query or matches(e["start"], query["start"]))
            and ("end" not in query or matches(e["end"], query["end"]))
            and ("node" not in query or matches(e["start"], query["node"]) or matches(e["end"], query["node"]))
            and ("rel" not in query or e["rel"]["@id"] == query["rel"])
        ]
        offset, limit = int(query.get("offset", 0)), int(query.get("limit", 50))
        base = "&".join(f"{k}={v}" for k, v in sorted(query.items()) if k not in ("offset", "limit"))
        view: dict[str, Any] = {"@id": f"/query?{base}&offset={offset}&limit={limit}",
                                "paginatedProperty": "edges"}
        if offset + limit < len(edges):
            view["nextPage"] = f"/query?{base}&offset={offset + limit}&limit={limit}"
        return Reply(200, {"@id": f"/query?{base}", "edges": edges[offset:offset + limit], "view": view})
