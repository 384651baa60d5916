"""Auth that works from a browser (issue 16): POST /ui/login with the token sets an HttpOnly,
SameSite=Strict session cookie (never the token) that the gated routes accept besides the
bearer header; the dashboard's shell is open; /ui/logout revokes the cookie."""
from __future__ import annotations

import httpx
import pytest

from .conftest import TOKEN, parse_sse, wait_for

# Slow: real tasks on a served Ray. Timeout: a task's event stream may take its 300 s after the server's start.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(420)]


def test_the_shell_is_open_and_the_data_is_not(server):
    for path, ctype in (("/ui", "text/html"), ("/ui/static/app.js", "text/javascript"),
                        ("/ui/static/app.css", "text/css")):
        r = httpx.get(server.base + path)
        assert r.status_code == 200 and r.headers["content-type"].startswith(ctype), path
        assert "script-src 'self'" in r.headers["content-security-policy"]
    assert httpx.get(server.base + "/ui/static/nope.js").status_code == 404
    assert httpx.get(server.base + "/v1/tasks").status_code == 401


def test_login_sets_a_session_cookie_that_is_not_the_token(server):
    with httpx.Client(base_url=server.base, timeout=60) as c:
        r = c.post("/ui/login", data={"token": TOKEN, "next": "/docs"})
        assert r.status_code == 303 and r.headers["location"] == "/docs"
        cookie = r.headers["set-cookie"]
        assert cookie.startswith("tmoc_session=")
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
        assert TOKEN not in cookie and TOKEN not in r.headers["location"]
        # the cookie opens the API, its schema and docs, and the event stream
        assert c.get("/v1/tasks").status_code == 200
        assert c.get("/openapi.json").json()["info"]["title"] == "TMOC service"
        assert c.get("/docs").status_code == 200
        task = c.post("/v1/tasks", json={"particles": 2, "episodes": 1, "max_steps": 2, "seed": 1}).json()["id"]
        with c.stream("GET", f"/v1/tasks/{task}/events", timeout=300) as s:
            assert s.status_code == 200 and s.headers["content-type"].startswith("text/event-stream")
            events = parse_sse(s.iter_lines())
        assert events[-1]["event"] == "status" and events[-1]["data"]["status"] == "succeeded"
        # sign out: the same cookie no longer works, even when replayed by hand
        value = c.cookies["tmoc_session"]
        out = c.post("/ui/logout")
        assert out.status_code == 303 and 'tmoc_session=""' in out.headers["set-cookie"]
        replay = httpx.get(server.base + "/v1/tasks", cookies={"tmoc_session": value})
        assert replay.status_code == 401
    assert TOKEN not in server.log()


def test_another_site_cannot_sign_the_browser_out(server):
    """Issue 25, row 14: a cross-site POST /ui/logout cleared the cookie."""
    with httpx.Client(base_url=server.base, timeout=60) as c:
        assert c.post("/ui/login", json={"token": TOKEN}).status_code == 200
        for headers in ({"Origin": "https://evil.example"}, {"Sec-Fetch-Site": "cross-site"},
                        {"Origin": "null"}, {"Origin": "null", "Sec-Fetch-Site": "same-site"}):
            r = c.post("/ui/logout", headers=headers)
            assert r.status_code == 403 and "set-cookie" not in r.headers, (headers, r.text)
            assert c.get("/v1/tasks").status_code == 200            # still signed in
        own = server.base.split("//", 1)[1]
        r = c.post("/ui/logout", headers={"Origin": f"http://{own}"})
        assert r.status_code == 303 and c.get("/v1/tasks").status_code == 401
        # what the dashboard's own Sign out sends (its page's policy is no-referrer)
        assert c.post("/ui/login", json={"token": TOKEN}).status_code == 200
        r = c.post("/ui/logout", headers={"Origin": "null", "Sec-Fetch-Site": "same-origin"})
        assert r.status_code == 303 and c.get("/v1/tasks").status_code == 401


def test_a_signed_in_browser_sees_the_running_task_on_health(server):
    """Issue 25, row 14: /health named the running task to a bearer only."""
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=server.base, timeout=60) as c:
        tid = c.post("/v1/tasks", headers=bearer, json={"particles": 8, "episodes": 6, "n_blocks": 8,
                                                         "max_steps": 60, "seed": 3}).json()["id"]
        try:
            wait_for(lambda: c.get("/health").json()["queued"] == 0
                     and c.get("/health", headers=bearer).json()["running"] == tid,
                     timeout=300, every=0.2, what="the task to run")
            assert c.get("/health").json()["running"] is None          # anonymous: not shown
            assert c.post("/ui/login", json={"token": TOKEN}).status_code == 200
            assert c.get("/health").json()["running"] == tid           # the cookie, no bearer
        finally:
            c.delete(f"/v1/tasks/{tid}", headers=bearer)


def test_bad_sign_ins_get_4xx_and_no_cookie(server):
    cases = [({"data": {"token": "wrong"}}, 401), ({"json": {"token": "wrong"}}, 401),
             ({"data": {"next": "/ui"}}, 422), ({"json": {"tok": TOKEN}}, 422),
             ({"content": b"{not json", "headers": {"content-type": "application/json"}}, 422)]
    for kw, status in cases:
        r = httpx.post(server.base + "/ui/login", **kw)
        assert r.status_code == status, (kw, r.text)
        assert "set-cookie" not in r.headers
    forged = httpx.get(server.base + "/v1/tasks", cookies={"tmoc_session": TOKEN})
    assert forged.status_code == 401           # the token is not a session id
    # JSON sign-in (for scripts): 200 and the cookie; an outside `next` is ignored
    r = httpx.post(server.base + "/ui/login", json={"token": TOKEN, "next": "https://evil.example/"})
    assert r.status_code == 200 and r.json()["next"] == "/ui" and "tmoc_session=" in r.headers["set-cookie"]
