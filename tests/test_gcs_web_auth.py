"""The web station's built-in authentication: where the token comes from, the refusal to serve beyond
loopback unprotected, and the station as a process checking every request and the WebSocket handshake."""
from __future__ import annotations

import asyncio
import http.client
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest

from gcs.web.auth import MIN_TOKEN_CHARS, TOKEN_ENV, Sessions, exposure_problem, load_token, token_matches
from sim.ports import free_tcp_port, free_udp_port

REPO = Path(__file__).resolve().parents[1]
TOKEN = "correct-horse-battery-staple-42"


def token_file(tmp_path: Path, text: str = TOKEN + "\n", mode: int = 0o600) -> Path:
    path = tmp_path / "gcs.token"
    path.write_text(text)
    path.chmod(mode)
    return path


def test_the_token_comes_from_a_file_or_the_environment_never_both(tmp_path: Path) -> None:
    assert load_token(None, {}) is None
    assert load_token(token_file(tmp_path), {}) == TOKEN
    assert load_token(None, {TOKEN_ENV: f"  {TOKEN}\n"}) == TOKEN
    with pytest.raises(ValueError, match="both set"):
        load_token(token_file(tmp_path), {TOKEN_ENV: TOKEN})
    with pytest.raises(ValueError, match=f"at least {MIN_TOKEN_CHARS} characters, got 6"):
        load_token(token_file(tmp_path, "secret\n"), {})
    with pytest.raises(ValueError, match=f"{TOKEN_ENV}: the token must have at least"):
        load_token(None, {TOKEN_ENV: "short"})
    with pytest.raises(ValueError, match="--token-file: cannot read"):
        load_token(tmp_path / "missing.token", {})


def test_serving_beyond_loopback_needs_a_token_or_a_proxy_that_checks() -> None:
    assert exposure_problem(True, None, False) is None  # the loopback default: SSH tunnel / proxy route
    assert exposure_problem(False, TOKEN, False) is None
    assert exposure_problem(False, None, True) is None
    problem = exposure_problem(False, None, False)
    assert problem is not None and "--token-file" in problem and "--behind-proxy" in problem


def test_token_and_session_checks() -> None:
    assert token_matches(TOKEN, TOKEN)
    assert not token_matches(TOKEN[:-1] + "x", TOKEN) and not token_matches("", TOKEN)
    assert not token_matches(None, TOKEN) and not token_matches(TOKEN + "x", TOKEN)
    sessions = Sessions(lifetime_s=10.0)
    session = sessions.open(now_s=100.0)
    assert len(session) >= 40 and sessions.valid(session, 105.0)
    assert not sessions.valid(session, 110.0)  # expired
    assert not sessions.valid(session[:-1] + "x", 105.0) and not sessions.valid(None, 105.0)
    sessions.close(session)
    assert not sessions.valid(session, 105.0)


def run_station(args: list[str], env: dict[str, str] | None = None, timeout_s: float = 30.0) -> subprocess.CompletedProcess:
    """`python -m gcs.web ARGS` expected to stop by itself (a refusal at start)."""
    return subprocess.run([sys.executable, "-m", "gcs.web", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout_s, env={**os.environ, "MAVLINK20": "1", **(env or {})})


def station_args(port: int = 0, host: str = "127.0.0.1") -> list[str]:
    return ["--mavlink", f"udpout:127.0.0.1:{free_udp_port()}", "--zenoh-listen", f"tcp/127.0.0.1:{free_tcp_port()}",
            "--host", host, "--port", str(port)]


def test_the_station_refuses_to_serve_beyond_loopback_without_a_token(tmp_path: Path) -> None:
    refused = run_station(station_args(host="0.0.0.0"))
    assert refused.returncode == 2
    assert "--host is not a loopback address and no token is set" in refused.stderr
    weak = run_station(station_args(), env={TOKEN_ENV: "secret"})
    assert weak.returncode == 2 and f"{TOKEN_ENV}: the token must have at least" in weak.stderr
    both = run_station([*station_args(), "--token-file", str(token_file(tmp_path))], env={TOKEN_ENV: TOKEN})
    assert both.returncode == 2 and "both set" in both.stderr


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, int]]:
    """The station as a process with a token file, on loopback; yields (host, port)."""
    from sim.web_station import WebStation

    folder = tmp_path_factory.mktemp("auth")
    args = station_args()
    with WebStation([args[1]], [], extra_args=(*args[2:4], "--token-file", str(token_file(folder)))) as running:
        address = running.url.removeprefix("http://").rstrip("/")
        host, port = address.rsplit(":", 1)
        yield host, int(port)


def request(station: tuple[str, int], method: str, path: str, headers: dict | None = None,
            body: str | None = None) -> http.client.HTTPResponse:
    connection = http.client.HTTPConnection(*station, timeout=10)
    connection.request(method, path, body=body, headers=headers or {})
    response = connection.getresponse()
    response.body = response.read()
    connection.close()
    return response


def websocket_opens(station: tuple[str, int], headers: dict[str, str]) -> bool:
    """Whether /ws accepts the handshake with these headers (and sends the drone list first)."""
    import websockets
    from websockets.exceptions import InvalidStatus

    async def attempt() -> bool:
        try:
            async with websockets.connect(f"ws://{station[0]}:{station[1]}/ws", additional_headers=headers,
                                          open_timeout=10) as socket:
                first = json.loads(await asyncio.wait_for(socket.recv(), 10))
                return first["type"] == "events"
        except InvalidStatus:
            return False
    return asyncio.run(attempt())


def test_every_request_and_the_websocket_need_the_token(station: tuple[str, int]) -> None:
    page = request(station, "GET", "/")
    assert page.status == 303 and page.getheader("location") == "/login"
    assert request(station, "GET", "/api/drones").status == 401
    assert request(station, "GET", "/static/app.js").status == 401
    assert request(station, "GET", "/api/drones", {"Authorization": "Bearer " + TOKEN[:-1] + "x"}).status == 401
    assert request(station, "GET", "/api/drones", {"Authorization": f"Bearer {TOKEN}"}).status == 200
    assert not websocket_opens(station, {})
    assert not websocket_opens(station, {"Cookie": "jsar_gcs_session=forged"})
    assert websocket_opens(station, {"Authorization": f"Bearer {TOKEN}"})

    form = {"Content-Type": "application/x-www-form-urlencoded"}
    wrong = request(station, "POST", "/login", form, "token=guess")
    assert wrong.status == 401 and b"Wrong token" in wrong.body and wrong.getheader("set-cookie") is None
    login = request(station, "POST", "/login", form, f"token={TOKEN}")
    assert login.status == 303 and login.getheader("location") == "/"
    cookie = login.getheader("set-cookie")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    session = {"Cookie": cookie.split(";")[0]}
    assert request(station, "GET", "/", session).status == 200
    assert websocket_opens(station, session)
    logout = request(station, "POST", "/logout", session)
    assert logout.status == 303
    assert request(station, "GET", "/api/drones", session).status == 401  # the session is gone


def test_an_operator_logs_in_from_the_browser_and_the_page_connects(station: tuple[str, int], tmp_path: Path) -> None:
    """Debian's Chromium through Playwright (tests/test_gcs_web_browser.py): the page sends the operator to the
    login form; a wrong token is refused there; the right one opens the page, whose WebSocket (the session
    cookie, no token in the page) connects."""
    from tests.test_gcs_web_browser import browser_page

    with browser_page(tmp_path) as page:
        page.goto(f"http://{station[0]}:{station[1]}/")
        assert page.url.endswith("/login")
        page.fill("#token", "not-the-token-at-all")
        page.click("#login")
        page.wait_for_selector("#error:has-text('Wrong token')", timeout=10_000)
        assert page.url.endswith("/login")
        page.fill("#token", TOKEN)
        page.click("#login")
        page.wait_for_url(f"http://{station[0]}:{station[1]}/", timeout=10_000)
        page.wait_for_selector("#connection:has-text('connected')", timeout=10_000)
        assert page.locator("#connection").inner_text() == "connected"
        assert page.errors == []


def asgi_call(app, scope: dict, body: bytes = b"") -> list[dict]:
    """One request through an ASGI app; the messages it sent."""
    sent: list[dict] = []

    async def receive() -> dict:
        return {"type": "http.request", "body": body, "more_body": False}

    async def send(message: dict) -> None:
        sent.append(message)
    asyncio.run(app(scope, receive, send))
    return sent


def test_wrong_tokens_from_one_address_are_throttled_for_a_minute() -> None:
    from gcs.web.auth import MAX_FAILURES, TokenAuth

    reached: list[str] = []

    async def page(scope, receive, send) -> None:  # what the middleware protects
        reached.append(scope["type"])
        if scope["type"] == "http":
            await send({"type": "http.response.start", "status": 200, "headers": []})
            await send({"type": "http.response.body", "body": b"page"})
    now = [1000.0]
    auth = TokenAuth(page, TOKEN, clock=lambda: now[0])

    def login(token: str, client: str = "10.0.0.7") -> int:
        scope = {"type": "http", "method": "POST", "path": "/login", "client": (client, 5000), "headers": []}
        return asgi_call(auth, scope, f"token={token}".encode())[0]["status"]

    def api(token: str, client: str = "10.0.0.7") -> int:
        scope = {"type": "http", "method": "GET", "path": "/api/drones", "client": (client, 5000),
                 "headers": [(b"authorization", f"Bearer {token}".encode())]}
        return asgi_call(auth, scope)[0]["status"]

    assert [login("guess-%d" % i) for i in range(MAX_FAILURES - 1)] == [401] * (MAX_FAILURES - 1)
    assert api("another-guess") == 401  # a wrong bearer token is a guess too: the limit is reached
    assert login(TOKEN) == 429 and api(TOKEN) == 429  # even the right token waits
    assert login(TOKEN, client="10.0.0.8") == 303  # another address is not held up
    now[0] += 59.0
    assert login(TOKEN) == 429
    now[0] += 2.0  # a minute after the first failures
    assert login(TOKEN) == 303 and api(TOKEN) == 200
    assert reached == ["http"]  # only the right token's request reached the page
    asgi_call(auth, {"type": "lifespan"})  # start-up and shut-down pass untouched
    assert reached == ["http", "lifespan"]
