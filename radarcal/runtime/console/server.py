"""A small local web server for the operator pages (live console, field-pnp clicking page): the standard library's
``ThreadingHTTPServer`` (one daemon thread per connection), server-sent events for the push, static assets shipped in
the package (no CDN: the station is offline).

Security (docs/console.md):

- binds 127.0.0.1 unless told otherwise (:func:`parse_bind`);
- a per-run token (printed on the terminal) for everything that acts: ``POST /api/claim`` with the token gives the
  page a session; every action then carries the token, that session and a sequence number that must increase
  (a replayed or reordered request is refused). One controlling session at a time: a second client is refused while
  the first one's event stream is open or it acted in the last ``hold_s`` seconds;
- read-only views go without the token only when bound to loopback;
- the ``Host`` header must name the bound address (no DNS rebinding) and a cross-site ``Origin`` is refused;
- every refusal is logged on stderr and kept (bounded) in :attr:`WebServer.refusals`.

Action handlers run in the HTTP thread and must not block the match loop: they set flags or put values in
bounded slots that the loop (or the page's owner) reads.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import secrets
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from radarcal.errors import InputError

__all__ = ["LatestSlot", "WebServer", "asset", "is_loopback", "parse_bind"]

CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
                 ".png": "image/png", ".jpg": "image/jpeg", ".svg": "image/svg+xml"}  # fmt: skip


def parse_bind(spec: str | int, what: str = "--ui") -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` (``[::1]:PORT`` for IPv6) -> (host, port); the host defaults to 127.0.0.1."""
    s = str(spec).strip()
    host = "127.0.0.1"
    if s.startswith("["):
        h, _, p = s[1:].partition("]")
        host, s = h, p.lstrip(":")
    elif ":" in s:
        host, s = s.rsplit(":", 1)
        host = host or "127.0.0.1"
    try:
        port = int(s)
    except ValueError:
        raise InputError(what, f"expected [HOST:]PORT, got {spec!r}") from None
    if not 0 <= port <= 65535:
        raise InputError(what, f"port must be 0..65535, got {port}")
    return host, port


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def asset(package: str, name: str) -> bytes:
    """A page asset shipped as package data (``radarcal/<...>/static/<name>``)."""
    return resources.files(package).joinpath("static", name).read_bytes()


class LatestSlot:
    """A bounded latest-value slot between a producer that must never wait (the match loop) and readers that may be
    slow (browser streams): ``put`` replaces the value and bumps a sequence number; readers wait for a sequence newer
    than the one they have. Older values are dropped, never queued."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.value: Any = None
        self.seq = 0

    def put(self, value: Any) -> None:
        # the lock is held only for two assignments; readers hold it only while waiting (wait() releases it)
        with self._cond:
            self.value = value
            self.seq += 1
            self._cond.notify_all()

    def get_newer(self, seq: int, timeout: float) -> tuple[int, Any]:
        """The newest (seq, value) if its seq > ``seq``, waiting up to ``timeout`` s; else (seq, None)."""
        with self._cond:
            if self.seq <= seq:
                self._cond.wait(timeout)
            if self.seq <= seq:
                return seq, None
            return self.seq, self.value


class _Refused(Exception):
    def __init__(self, status: int, why: str):
        super().__init__(why)
        self.status = status
        self.why = why


class WebServer:
    """Routes: ``get[path] = fn(query) -> (content_type, bytes)``, ``streams[path] = fn(write, query, alive)`` (SSE),
    ``actions[name] = fn(args: dict) -> dict`` (``POST /api/action/<name>``, token + session + sequence)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, name: str = "console", token: str | None = None, hold_s: float = 15.0, log=None):
        self.name = name
        self.token = token or secrets.token_urlsafe(18)
        self.hold_s = hold_s
        self.get: dict[str, Callable] = {}
        self.streams: dict[str, Callable] = {}
        self.actions: dict[str, Callable] = {}
        self.refusals: deque = deque(maxlen=200)
        self.accepted: deque = deque(maxlen=200)
        self._log = log or (lambda line: (sys.stderr.write(line + "\n"), sys.stderr.flush()))
        self._lock = threading.Lock()
        self._session: str | None = None
        self._session_seen = 0.0
        self._session_streams = 0
        self._last_seq = -1
        self._stop = threading.Event()
        srv = self

        class Handler(_Handler):
            server_app = srv

        try:
            self.httpd = ThreadingHTTPServer((host, port), Handler)
        except OSError as e:
            raise InputError("--ui", f"cannot listen on {host}:{port} ({e.strerror or e})") from None
        self.httpd.daemon_threads = True
        self.host = host
        self.port = self.httpd.server_address[1]
        self.loopback = is_loopback(host)
        self._thread: threading.Thread | None = None
        self.streams["/api/hold"] = self._hold_stream  # a page with the controls keeps this open: the session is held

    def _hold_stream(self, write, q: dict, alive) -> None:
        while alive():
            write("ping", "{}")
            self._stop.wait(1.0)  # a closed page is noticed at the second write after it went

    # --- lifecycle --------------------------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        h = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{h}:{self.port}/"

    def start(self) -> WebServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True, name=f"{self.name}-http")
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self.httpd.shutdown()
        self.httpd.server_close()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def announce(self) -> None:
        """The terminal line with the address and the token (the only place the token is shown)."""
        self._log(f"{self.name}: {self.url}#token={self.token}  (bound to {self.host}{'' if self.loopback else ' - NOT loopback: every view needs the token'};"
                  f" actions need the token {self.token})")  # fmt: skip

    def serve_until(self, done: threading.Event, ready=None, closed_message: str = "closed: nothing written") -> None:
        """Start, print the address and token, call ``ready(self)`` (tests), block until ``done`` is set by an action
        (then give its response a moment to reach the page), and close. Ctrl-C -> InputError(``--ui``,
        ``closed_message``): a page closed without its action has written nothing."""
        from radarcal.errors import InputError

        self.start()
        self.announce()
        if ready is not None:
            ready(self)
        try:
            while not done.wait(0.2):
                pass
            done.wait(0.3)
        except KeyboardInterrupt:
            raise InputError("--ui", closed_message) from None
        finally:
            self.close()

    # --- checks -----------------------------------------------------------------------------------------------------
    def refuse(self, addr: str, path: str, status: int, why: str) -> None:
        self.refusals.append({"t": time.time(), "client": addr, "path": path, "status": status, "why": why})
        self._log(f"{self.name}: refused {path} from {addr}: {why}")

    def token_ok(self, given: str | None) -> bool:
        return bool(given) and hmac.compare_digest(str(given).encode(), self.token.encode())

    def check_host(self, host_header: str | None, origin: str | None) -> None:
        if not self.loopback:
            return  # reached through the network: the token protects every view
        host = (host_header or "").rsplit(":", 1)[0].strip("[]").lower()
        if host not in ("127.0.0.1", "localhost", "::1", self.host.lower()):
            raise _Refused(HTTPStatus.FORBIDDEN, f"Host header {host_header!r} is not this loopback server")
        if origin and origin != "null":
            o = urlsplit(origin)
            if o.hostname not in ("127.0.0.1", "localhost", "::1", self.host) or (o.port or 80) != self.port:
                raise _Refused(HTTPStatus.FORBIDDEN, f"cross-site Origin {origin!r}")

    def check_read(self, token: str | None) -> None:
        if not self.loopback and not self.token_ok(token):
            raise _Refused(HTTPStatus.UNAUTHORIZED, "not bound to loopback: views need the token")

    def claim(self, token: str | None) -> str:
        if not self.token_ok(token):
            raise _Refused(HTTPStatus.UNAUTHORIZED, "claim without the right token")
        with self._lock:
            now = time.monotonic()
            if self._session is not None and (self._session_streams > 0 or now - self._session_seen < self.hold_s):
                raise _Refused(HTTPStatus.CONFLICT, "another client holds the controls (close it, or wait until its page has been gone for "
                                                    f"{self.hold_s:g} s)")  # fmt: skip
            self._session = secrets.token_urlsafe(12)
            self._session_seen = now
            self._last_seq = -1
            return self._session

    def check_action(self, token: str | None, session: str | None, seq: Any) -> None:
        if not self.token_ok(token):
            raise _Refused(HTTPStatus.UNAUTHORIZED, "missing or wrong token")
        with self._lock:
            if self._session is None or not session or not hmac.compare_digest(str(session).encode(), self._session.encode()):
                raise _Refused(HTTPStatus.CONFLICT, "not the controlling session (a second client, or claim first)")
            if not isinstance(seq, int) or isinstance(seq, bool) or seq <= self._last_seq:
                raise _Refused(HTTPStatus.CONFLICT, f"sequence {seq!r} not after {self._last_seq} (a replayed or reordered request)")
            self._last_seq = seq
            self._session_seen = time.monotonic()

    def stream_opened(self, session: str | None) -> bool:
        with self._lock:
            if session and self._session and hmac.compare_digest(str(session).encode(), self._session.encode()):
                self._session_streams += 1
                return True
            return False

    def stream_closed(self) -> None:
        with self._lock:
            self._session_streams = max(0, self._session_streams - 1)
            self._session_seen = time.monotonic()


class _Handler(BaseHTTPRequestHandler):
    server_app: WebServer
    protocol_version = "HTTP/1.1"
    timeout = 30  # a client that stops reading frees its thread; the loop never waits for it

    def log_message(self, format: str, *args) -> None:
        pass

    def _client(self) -> str:
        return f"{self.client_address[0]}:{self.client_address[1]}"

    def _send(self, status: int, ctype: str, body: bytes, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, obj: Any) -> None:
        self._send(status, "application/json", json.dumps(obj, separators=(",", ":"), default=_jsonable).encode())

    def _refused(self, e: _Refused) -> None:
        app = self.server_app
        app.refuse(self._client(), f"{self.command} {urlsplit(self.path).path}", int(e.status), e.why)
        self._json(int(e.status), {"error": e.why})

    def do_GET(self) -> None:
        app = self.server_app
        url = urlsplit(self.path)
        q = {k: v[-1] for k, v in parse_qs(url.query).items()}
        try:
            app.check_host(self.headers.get("Host"), self.headers.get("Origin"))
            app.check_read(q.get("token") or self.headers.get("X-Radarcal-Token"))
            if url.path in app.streams:
                self._stream(url.path, q)
                return
            fn = app.get.get(url.path)
            if fn is None:
                self._json(404, {"error": "not found"})
                return
            ctype, body = fn(q)
            self._send(200, ctype, body)
        except _Refused as e:
            self._refused(e)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            pass

    def _stream(self, path: str, q: dict) -> None:
        app = self.server_app
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Accel-Buffering", "no")
        self.end_headers()
        self.close_connection = True
        held = app.stream_opened(q.get("session"))

        def write(event: str | None, data: str) -> None:
            msg = (f"event: {event}\n" if event else "") + "".join(f"data: {line}\n" for line in data.split("\n")) + "\n"
            self.wfile.write(msg.encode())
            self.wfile.flush()

        try:
            app.streams[path](write, q, lambda: not app.stopping)
        except (BrokenPipeError, ConnectionResetError, TimeoutError, OSError):
            pass  # the page went away: nothing to do, the producer never noticed
        finally:
            if held:
                app.stream_closed()

    def do_POST(self) -> None:
        app = self.server_app
        url = urlsplit(self.path)
        try:
            app.check_host(self.headers.get("Host"), self.headers.get("Origin"))
            n = int(self.headers.get("Content-Length") or 0)
            if n > 4_000_000:
                raise _Refused(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"request body of {n} bytes")
            raw = self.rfile.read(n) if n else b"{}"
            try:
                body = json.loads(raw or b"{}")
            except ValueError:
                raise _Refused(HTTPStatus.BAD_REQUEST, "body is not JSON") from None
            if not isinstance(body, dict):
                raise _Refused(HTTPStatus.BAD_REQUEST, "body is not a JSON object")
            token = self.headers.get("X-Radarcal-Token")
            if url.path == "/api/claim":
                self._json(200, {"session": app.claim(token)})
                return
            if not url.path.startswith("/api/action/"):
                raise _Refused(HTTPStatus.NOT_FOUND, "no such endpoint")
            name = url.path[len("/api/action/"):]
            fn = app.actions.get(name)
            if fn is None:
                raise _Refused(HTTPStatus.NOT_FOUND, f"no action {name!r}")
            app.check_action(token, body.get("session"), body.get("seq"))
            args = body.get("args") or {}
            if not isinstance(args, dict):
                raise _Refused(HTTPStatus.BAD_REQUEST, "args must be an object")
            try:
                out = fn(args)
            except (ValueError, KeyError, TypeError, InputError) as e:
                raise _Refused(HTTPStatus.UNPROCESSABLE_ENTITY, f"{name}: {e}") from None
            app.accepted.append({"t": time.time(), "client": self._client(), "action": name, "seq": body.get("seq")})
            self._json(200, out if isinstance(out, dict) else {"ok": True})
        except _Refused as e:
            self._refused(e)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            pass


def _jsonable(o: Any):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return str(o)
