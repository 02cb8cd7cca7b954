"""Shared by the tests that point real SDK clients (openai, google-genai) at a local server."""

from __future__ import annotations

import json
import threading
from contextlib import contextmanager
from http.server import ThreadingHTTPServer

API_KEY_VARS = ("OPENAI_API_KEY", "OPENAI_BASE_URL", "GOOGLE_API_KEY", "GEMINI_API_KEY")
PROXY_VARS = ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy")


@contextmanager
def serving(fake, handler_cls):
    """Serve ``handler_cls`` on an ephemeral loopback port; ``fake.url`` gets its address and
    ``fake.release`` (an Event that stalled handlers wait on) is set before shutting down."""
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), handler_cls)
    httpd.daemon_threads = True
    fake.url = f"http://127.0.0.1:{httpd.server_port}"
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        yield fake
    finally:
        fake.release.set()
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=5)


def send_json(handler, status: int, payload: dict) -> None:
    """Answer ``handler``'s request with ``payload`` as JSON; a client that already hung up
    (a cancelled verification, a timeout test) is nobody's error."""
    data = json.dumps(payload).encode()
    try:
        handler.send_response(status)
        handler.send_header("content-type", "application/json")
        handler.send_header("content-length", str(len(data)))
        handler.end_headers()
        handler.wfile.write(data)
    except (BrokenPipeError, ConnectionResetError):
        pass


def scrub_env(monkeypatch) -> None:
    """No real keys, URLs or proxies from the machine leak into these tests."""
    for var in API_KEY_VARS + PROXY_VARS:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("NO_PROXY", "127.0.0.1,localhost")
