"""The studio's websocket admits its own page and the origins named with `--allow-origin`, and
refuses every other web origin at the handshake: a real studio on 127.0.0.1 (an ephemeral
port), real websocket clients that send the Origin header a browser would."""

from __future__ import annotations

import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from learner.live import studio as studio_mod
from learner.live.origin_guard import OriginPolicy, parse_origin
from learner.live.studio import Studio

TRUSTED = "http://trusted.example:9000"


@pytest.fixture(scope="module")
def studio():
    st = Studio("lower_biped", host="127.0.0.1", port=0, allow_origins=(TRUSTED,)).start()
    try:
        yield st
    finally:
        st.stop()


def _open(studio: Studio, origin: str | None):
    """A websocket to the studio as viser's page opens it, with `origin` (None: no header)."""
    url = f"ws://127.0.0.1:{studio.server.get_port()}/"
    return connect(url, origin=origin, subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10, close_timeout=2)


def test_a_foreign_origin_is_refused_before_any_scene_data(studio) -> None:
    before = sum(studio.origins.refused.values())
    for origin in ("http://evil.example", f"http://localhost.evil.example:{studio.server.get_port()}", "null"):
        with pytest.raises(InvalidStatus) as refused:
            _open(studio, origin)
        assert refused.value.response.status_code == 403, origin
    assert sum(studio.origins.refused.values()) == before + 3
    assert studio.server.get_clients() == {}


@pytest.mark.parametrize("origin", ["own", "localhost", TRUSTED, None])
def test_the_studios_own_page_and_allowed_origins_get_the_scene(studio, origin) -> None:
    port = studio.server.get_port()
    origin = {"own": f"http://127.0.0.1:{port}", "localhost": None}.get(origin, origin)
    with _open(studio, origin) as ws:
        assert isinstance(ws.recv(timeout=15), bytes)  # the scene stream starts
    if origin is None:  # and the studio's page reached as localhost: the Host header names it
        with connect(f"ws://localhost:{port}/", origin=f"http://localhost:{port}",
                     subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10) as ws:
            assert isinstance(ws.recv(timeout=15), bytes)


def test_dns_rebinding_is_not_same_origin() -> None:
    policy = OriginPolicy()
    assert policy.allows("http://127.0.0.1:8080", "127.0.0.1:8080")
    assert policy.allows("http://[::1]:8080", "[::1]:8080")
    assert policy.allows("http://192.0.2.7:8080", "192.0.2.7:8080")  # --host 0.0.0.0 reached by address
    assert not policy.allows("http://rebound.example:8080", "rebound.example:8080")  # a name may point anywhere
    assert not policy.allows("http://127.0.0.1:8081", "127.0.0.1:8080")
    assert not policy.allows("https://127.0.0.1:8080", "127.0.0.1:8080")
    assert not policy.allows("http://127.0.0.1:99999", "127.0.0.1:99999")  # a malformed Host refuses, never raises
    assert not policy.allows("http://127.0.0.1:8080", "")
    assert OriginPolicy(["http://rebound.example:8080/"]).allows("http://rebound.example:8080", "x:1")


@pytest.mark.parametrize("bad", ["myhost:8080", "ftp://myhost", "http://myhost:8080/page", "http://", "http://h:99999"])
def test_a_bad_allow_origin_is_one_line_exit_2(bad, capsys) -> None:
    with pytest.raises(ValueError):
        parse_origin(bad)
    with pytest.raises(SystemExit) as exited:
        studio_mod.main(["--allow-origin", bad, "--seconds", "1"])
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("morphmimic studio: ") and "--allow-origin" in err and "\n" not in err
