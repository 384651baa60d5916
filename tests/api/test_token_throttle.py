"""Tokens that cannot be guessed fast or used to lock others out (issue 38, finding 4), on a
real `tmoc serve`: a wrong bearer token counts like a failed sign-in of its address, the
throttle refuses the guessing address and nobody else, and a proxy's X-Forwarded-For
picks the counted address only where `--forwarded-allow-ips` trusts that proxy.

Loopback is 127.0.0.0/8 on Linux, so clients bound to 127.0.0.2, .3, ... are distinct
addresses to the server without any header."""
from __future__ import annotations

import httpx
import pytest

from api.auth import LoginThrottle

from .conftest import Server


def _client(server: Server, address: str) -> httpx.Client:
    return httpx.Client(base_url=server.base, timeout=10,
                        transport=httpx.HTTPTransport(local_address=address))


def _guess(c: httpx.Client, n: int, **headers) -> list[int]:
    return [c.get("/v1/tasks", headers={"Authorization": f"Bearer wrong-{k}", **headers}).status_code
            for k in range(n)]


@pytest.mark.timeout(300)
@pytest.mark.slow
def test_bearer_guesses_are_throttled_per_address(tmp_path):
    srv = Server(tmp_path / "auth.sqlite").start()
    try:
        with _client(srv, "127.0.0.2") as guesser, _client(srv, "127.0.0.3") as robot:
            assert _guess(guesser, 10) == [401] * 10
            refused = guesser.get("/v1/tasks", headers={"Authorization": "Bearer wrong-again"})
            assert refused.status_code == 429 and 1 <= int(refused.headers["retry-after"]) <= 60, refused.text
            # The right token from the guessing address waits too (else 429 against 200
            # would tell a guesser when it is right) ...
            assert guesser.get("/v1/tasks", headers=srv.headers).status_code == 429
            assert guesser.post("/ui/login", json={"token": srv.token}).status_code == 429
            # ... and everyone else goes on, /health included.
            assert robot.get("/v1/tasks", headers=srv.headers).status_code == 200
            assert guesser.get("/health").status_code == 200
            # A request with no credential is not a guess: it never counts.
            assert [robot.get("/v1/tasks").status_code for _ in range(15)] == [401] * 15
            assert robot.get("/v1/tasks", headers=srv.headers).status_code == 200
            # A proxy header from loopback is not trusted by default: the guesses count
            # against the connection's address, whatever X-Forwarded-For says.
            with _client(srv, "127.0.0.4") as proxied:
                codes = [proxied.get("/v1/tasks", headers={"Authorization": f"Bearer w{k}",
                                                           "X-Forwarded-For": f"10.0.0.{k}"}).status_code
                         for k in range(11)]
                assert codes == [401] * 10 + [429], codes
    finally:
        srv.stop()


@pytest.mark.timeout(300)
@pytest.mark.slow
def test_a_trusted_proxys_header_names_the_address(tmp_path):
    srv = Server(tmp_path / "proxy.sqlite", "--forwarded-allow-ips", "127.0.0.5").start()
    try:
        with _client(srv, "127.0.0.5") as proxy:
            assert _guess(proxy, 11, **{"X-Forwarded-For": "10.1.1.1"}) == [401] * 10 + [429]
            ok = proxy.get("/v1/tasks", headers={**srv.headers, "X-Forwarded-For": "10.1.1.2"})
            assert ok.status_code == 200, ok.text
    finally:
        srv.stop()


def test_many_guessing_addresses_do_not_lock_out_a_new_one():
    t = LoginThrottle(per_address=10, in_all=100, window_s=60.0)
    for k in range(100):                               # 100 failures from 20 addresses
        t.failed(f"10.0.0.{k % 20}", 0.0)
    assert t.retry_after("10.0.0.3", 1.0) == pytest.approx(59.0)    # a guesser waits
    assert t.retry_after("192.168.1.7", 1.0) is None               # a newcomer does not
    assert t.retry_after("10.0.0.3", 61.0) is None                 # aged out
    for _ in range(10):
        t.failed("a", 100.0)
    assert t.retry_after("a", 100.5) == pytest.approx(59.5) and t.retry_after("b", 100.5) is None
