"""The web station's optional built-in authentication: one shared token, for operators without an SSH tunnel
or an authenticating reverse proxy (docs/security.md).

- The token comes from a file (`--token-file`) or the environment (`JSAR_GCS_TOKEN`), never from the
  command line (other users of the machine can read a process's arguments).
- A browser logs in once with a form (`GET /login`, `POST /login` with `token=...`) and gets a session
  cookie (random id, HttpOnly, SameSite=Strict); a script sends `Authorization: Bearer TOKEN`.
- Every HTTP request and the WebSocket handshake are checked (ASGI middleware): without a valid session or
  header, a page request is sent to /login, anything else gets 401, a WebSocket is closed (1008) before it
  is accepted. Tokens are compared in constant time (hmac.compare_digest); an address that sends
  MAX_FAILURES wrong tokens within a minute is refused (429) until the minute has passed.
"""
from __future__ import annotations

import hmac
import html
import logging
import secrets
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Awaitable, Callable, Mapping
from urllib.parse import parse_qs

log = logging.getLogger("gcs.web")
TOKEN_ENV = "JSAR_GCS_TOKEN"
MIN_TOKEN_CHARS = 16  # a shorter token is guessable: refused at start
COOKIE = "jsar_gcs_session"
SESSION_S = 12 * 3600.0  # a login lasts a working day, then the form again
MAX_SESSIONS = 256  # the oldest login is forgotten past this (a flood of logins cannot grow memory)
MAX_FORM_BYTES = 4096  # a login form is one short field
MAX_FAILURES = 5  # wrong tokens from one address within FAILURE_WINDOW_S, and it is refused (429) ...
FAILURE_WINDOW_S = 60.0  # ... until the oldest of them is this old (s): guessing stays slow
MAX_CLIENTS = 1024  # addresses remembered with failures (the oldest forgotten first)

Scope = dict[str, Any]
Receive = Callable[[], Awaitable[dict[str, Any]]]
Send = Callable[[dict[str, Any]], Awaitable[None]]


def load_token(token_file: Path | None, environ: Mapping[str, str]) -> str | None:
    """The token from token_file (its first line) or environ[TOKEN_ENV]; None if neither is set.
    ValueError if both are set, the file cannot be read, or the token is shorter than MIN_TOKEN_CHARS."""
    from_env = environ.get(TOKEN_ENV, "").strip()
    if token_file is not None and from_env:
        raise ValueError(f"--token-file and {TOKEN_ENV} are both set: give the token one way")
    if token_file is not None:
        try:
            lines = token_file.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"--token-file: cannot read {token_file}: {exc}") from exc
        token, where = (lines[0].strip() if lines else ""), f"--token-file {token_file}"
        if token_file.stat().st_mode & 0o077:
            log.warning("event=token_file_readable_by_others path=%s: chmod 600 it", token_file)
    elif from_env:
        token, where = from_env, TOKEN_ENV
    else:
        return None
    if len(token) < MIN_TOKEN_CHARS:
        raise ValueError(f"{where}: the token must have at least {MIN_TOKEN_CHARS} characters, got {len(token)}")
    return token


def exposure_problem(host_is_loopback: bool, token: str | None, behind_proxy: bool) -> str | None:
    """Why the station must not start (serving beyond this machine with nobody checking who connects), or
    None."""
    if host_is_loopback or token is not None or behind_proxy:
        return None
    return (f"--host is not a loopback address and no token is set: anyone who reaches it could command the "
            f"drones. Set a token (--token-file FILE or {TOKEN_ENV}), or pass --behind-proxy when an "
            f"authenticating reverse proxy in front of it checks every request (docs/security.md)")


def token_matches(given: str | None, token: str) -> bool:
    """given == token, in time independent of where they differ."""
    return given is not None and hmac.compare_digest(given.encode("utf-8"), token.encode("utf-8"))


@dataclass
class Sessions:
    """Logged-in browsers: random session id -> expiry (time.monotonic() s), oldest first."""

    lifetime_s: float = SESSION_S
    _expiry: OrderedDict = field(default_factory=OrderedDict)

    def open(self, now_s: float) -> str:
        """A new session id (32 random bytes, URL-safe)."""
        session = secrets.token_urlsafe(32)
        self._expiry[session] = now_s + self.lifetime_s
        while len(self._expiry) > MAX_SESSIONS:
            self._expiry.popitem(last=False)
        return session

    def valid(self, session: str | None, now_s: float) -> bool:
        if not session:
            return False
        for known, expiry in self._expiry.items():  # compared in constant time, like the token
            if hmac.compare_digest(known.encode(), session.encode()):
                return now_s < expiry
        return False

    def close(self, session: str | None) -> None:
        self._expiry.pop(session or "", None)


@dataclass
class Throttle:
    """Wrong tokens by client address: more than `limit` in `window_s` seconds and the address is blocked."""

    limit: int = MAX_FAILURES
    window_s: float = FAILURE_WINDOW_S
    _failures: OrderedDict = field(default_factory=OrderedDict)  # address -> [monotonic s of each failure]

    def blocked(self, client: str, now_s: float) -> bool:
        times = [t for t in self._failures.get(client, []) if now_s - t < self.window_s]
        return len(times) >= self.limit

    def failed(self, client: str, now_s: float) -> None:
        times = [t for t in self._failures.pop(client, []) if now_s - t < self.window_s]
        self._failures[client] = [*times, now_s][-self.limit:]
        while len(self._failures) > MAX_CLIENTS:
            self._failures.popitem(last=False)


def header(scope: Scope, name: bytes) -> str | None:
    """A request header's value (latin-1), or None."""
    for key, value in scope.get("headers", ()):
        if key.lower() == name:
            return value.decode("latin-1")
    return None


def cookie(scope: Scope, name: str) -> str | None:
    """A cookie's value from the Cookie header, or None."""
    for part in (header(scope, b"cookie") or "").split(";"):
        key, _, value = part.strip().partition("=")
        if key == name:
            return value
    return None


def client_address(scope: Scope) -> str:
    """The connecting address (behind a proxy: the proxy's)."""
    client = scope.get("client")
    return str(client[0]) if client else "?"


def bearer(scope: Scope) -> str | None:
    """The token of an `Authorization: Bearer TOKEN` header, or None."""
    value = header(scope, b"authorization") or ""
    scheme, _, token = value.partition(" ")
    return token.strip() if scheme.lower() == "bearer" else None


LOGIN_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width">
<title>JSAR ground station: log in</title>
<style>body{{font-family:sans-serif;background:#111;color:#eee;display:flex;justify-content:center;
padding-top:15vh}}form{{display:flex;flex-direction:column;gap:.6em;min-width:20em}}
input,button{{font-size:1em;padding:.4em}}.error{{color:#f66}}</style></head>
<body><form method="post" action="/login"><h1>JSAR ground station</h1>
<label for="token">Access token</label>
<input id="token" name="token" type="password" autocomplete="current-password" autofocus required>
<button id="login" type="submit">Log in</button><p class="error" id="error">{error}</p></form></body></html>
"""


class TokenAuth:
    """ASGI middleware: lets through requests with a valid session cookie or bearer token, serves /login and
    /logout itself, and refuses everything else (lifespan events pass untouched)."""

    def __init__(self, app: Callable, token: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.app, self.token, self.clock = app, token, clock
        self.sessions = Sessions()
        self.throttle = Throttle()

    def allowed(self, scope: Scope) -> bool:
        """A valid bearer token or session cookie (a wrong bearer token counts as a failed guess)."""
        given = bearer(scope)
        if given is not None:
            if token_matches(given, self.token):
                return True
            self.throttle.failed(client_address(scope), self.clock())
        return self.sessions.valid(cookie(scope, COOKIE), self.clock())

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "")
        guessing = bearer(scope) is not None or (path == "/login" and scope.get("method") == "POST")
        if guessing and self.throttle.blocked(client_address(scope), self.clock()):
            log.warning("event=login_throttled client=%s", client_address(scope))
            if kind == "websocket":
                await send({"type": "websocket.close", "code": 1008})
            else:
                await respond(send, 429, b"too many wrong tokens: wait a minute\n", [(b"content-type", b"text/plain")])
            return
        if kind == "http" and path == "/login":
            await self.login(scope, receive, send)
            return
        if kind == "http" and path == "/logout" and scope.get("method") == "POST":
            self.sessions.close(cookie(scope, COOKIE))
            await respond(send, 303, b"", [(b"location", b"/login"),
                                          (b"set-cookie", f"{COOKIE}=; Path=/; Max-Age=0".encode())])
            return
        if self.allowed(scope):
            await self.app(scope, receive, send)
            return
        if kind == "websocket":
            log.warning("event=websocket_unauthenticated client=%s", client_address(scope))
            await send({"type": "websocket.close", "code": 1008})
        elif scope.get("method") == "GET" and path == "/":
            await respond(send, 303, b"", [(b"location", b"/login")])
        else:
            await respond(send, 401, b"authentication required\n", [(b"content-type", b"text/plain"),
                                                                    (b"www-authenticate", b"Bearer")])

    async def login(self, scope: Scope, receive: Receive, send: Send) -> None:
        """GET: the form. POST: check the token; a session cookie and back to the page, or the form again."""
        if scope.get("method") != "POST":
            await respond(send, 200, LOGIN_PAGE.format(error="").encode(), [(b"content-type", b"text/html")])
            return
        body = b""
        while True:
            message = await receive()
            body += message.get("body", b"")
            if len(body) > MAX_FORM_BYTES:
                await respond(send, 413, b"login form too large\n", [(b"content-type", b"text/plain")])
                return
            if not message.get("more_body"):
                break
        given = parse_qs(body.decode("utf-8", "replace")).get("token", [None])[0]
        client = client_address(scope)
        if not token_matches(given, self.token):
            self.throttle.failed(client, self.clock())
            log.warning("event=login_refused client=%s", client)
            page = LOGIN_PAGE.format(error=html.escape("Wrong token.")).encode()
            await respond(send, 401, page, [(b"content-type", b"text/html")])
            return
        session = self.sessions.open(self.clock())
        secure = "; Secure" if scope.get("scheme") == "https" else ""
        log.info("event=login client=%s", client)
        await respond(send, 303, b"", [
            (b"location", b"/"),
            (b"set-cookie", f"{COOKIE}={session}; Path=/; HttpOnly; SameSite=Strict; "
                            f"Max-Age={int(SESSION_S)}{secure}".encode())])


async def respond(send: Send, status: int, body: bytes, headers: list[tuple[bytes, bytes]]) -> None:
    """One complete HTTP response (no caching: a login page or a refusal)."""
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-length", str(len(body)).encode()), (b"cache-control", b"no-store"), *headers]})
    await send({"type": "http.response.body", "body": body})
