"""A thin client of the `csmetro serve` HTTP/JSON API (standard library only).

Every call is one request; errors from the service raise :class:`ApiError` with its HTTP status
and the service's own message (``{"error": "..."}``).
"""

from __future__ import annotations

import json
import os
import time
import urllib.error
import urllib.parse
import urllib.request
from typing import Any, Callable, Iterator, Optional

#: States after which a campaign produces nothing more on its own. ``interrupted`` is resumable
#: by an operator (``POST /campaigns/{id}/resume``) but waits for one.
FINAL_STATES = frozenset({"done", "failed", "aborted", "interrupted"})

DEFAULT_SERVER = "http://127.0.0.1:8463"


class ApiError(RuntimeError):
    """The service refused a request (``status``: HTTP status, ``message``: its reason) or could
    not be reached (``status`` 0)."""

    def __init__(self, status: int, message: str, *, method: str = "", path: str = ""):
        self.status = status
        self.message = message
        self.method = method
        self.path = path
        where = f"{method} {path}: " if method else ""
        code = f"HTTP {status}: " if status else ""
        super().__init__(f"{where}{code}{message}")


class Client:
    """The service at ``server`` (default: ``CSMETRO_SERVER``, else http://127.0.0.1:8463).

    ``token`` (default ``CSMETRO_TOKEN``) is sent as ``Authorization: Bearer``; ``operator``
    (default ``CSMETRO_OPERATOR``) as ``X-Operator``, so the service's audit trail names who
    submitted, paused, resumed or aborted.
    """

    def __init__(
        self,
        server: Optional[str] = None,
        *,
        token: Optional[str] = None,
        operator: Optional[str] = None,
        timeout: float = 30.0,
    ):
        self.server = (server or os.environ.get("CSMETRO_SERVER") or DEFAULT_SERVER).rstrip("/")
        self.token = token if token is not None else os.environ.get("CSMETRO_TOKEN") or None
        self.operator = (
            operator if operator is not None else os.environ.get("CSMETRO_OPERATOR") or None
        )
        self.timeout = timeout

    def __repr__(self) -> str:
        return f"Client({self.server!r}, operator={self.operator!r})"

    # -- transport ----------------------------------------------------------------------------

    def _headers(self, content_type: Optional[str] = None) -> dict[str, str]:
        h = {}
        if self.token:
            h["Authorization"] = f"Bearer {self.token}"
        if self.operator:
            h["X-Operator"] = self.operator
        if content_type:
            h["Content-Type"] = content_type
        return h

    def request(
        self,
        method: str,
        path: str,
        body: Optional[bytes] = None,
        content_type: Optional[str] = None,
        *,
        accept: str = "application/json",
        timeout: Any = ...,
    ):
        """One request; returns the open response (2xx) or raises :class:`ApiError`.
        ``timeout``: seconds, ``None`` for none (a stream), default the client's."""
        headers = self._headers(content_type)
        headers["Accept"] = accept
        req = urllib.request.Request(self.server + path, data=body, method=method, headers=headers)
        try:
            return urllib.request.urlopen(req, timeout=self.timeout if timeout is ... else timeout)
        except urllib.error.HTTPError as e:
            raw = e.read()
            try:
                message = json.loads(raw)["error"]
            except (ValueError, KeyError, TypeError):
                message = raw.decode("utf-8", "replace").strip() or str(e.reason)
            raise ApiError(e.code, str(message), method=method, path=path) from None
        except OSError as e:  # URLError, refused, reset, timed out
            reason = getattr(e, "reason", e)
            raise ApiError(
                0, f"cannot reach {self.server}: {reason}", method=method, path=path
            ) from None

    def _json(self, method: str, path: str, body: Any = None, content_type: Optional[str] = None):
        if body is not None and not isinstance(body, bytes):
            body = json.dumps(body).encode()
            content_type = content_type or "application/json"
        with self.request(method, path, body, content_type) as r:
            return json.loads(r.read())

    # -- the API ------------------------------------------------------------------------------

    def health(self) -> dict:
        """``GET /health``: ``{"status", "version", "running", "queued"}``."""
        return self._json("GET", "/health")

    def campaigns(self) -> list[dict]:
        """``GET /campaigns``: every campaign's status, newest first."""
        return self._json("GET", "/campaigns")

    def submit(self, toml: str, name: Optional[str] = None) -> dict:
        """``POST /campaigns`` with the campaign file's text; ``name`` (a file name) is what the
        service's errors call it. Returns the new campaign's status (its ``id``). An invalid
        campaign raises :class:`ApiError` 400 naming the line and key."""
        payload = {"toml": toml}
        if name:
            payload["name"] = name
        return self._json("POST", "/campaigns", payload)

    def status(self, campaign_id: int) -> dict:
        """``GET /campaigns/{id}``: ``id, name, stage, state, planned, stored, percent, message,
        queue_position, elapsed_s, eta_s`` ..."""
        return self._json("GET", f"/campaigns/{int(campaign_id)}")

    def _control(self, campaign_id: int, action: str) -> dict:
        # A JSON body: the service refuses the types a browser may send on its own.
        return self._json("POST", f"/campaigns/{int(campaign_id)}/{action}", {})

    def pause(self, campaign_id: int) -> dict:
        """Hold the campaign between two points (a queued one waits until resumed)."""
        return self._control(campaign_id, "pause")

    def resume(self, campaign_id: int) -> dict:
        """Continue a paused campaign (or queue an interrupted one again)."""
        return self._control(campaign_id, "resume")

    def abort(self, campaign_id: int) -> dict:
        """Stop motion and end the campaign ``aborted``."""
        return self._control(campaign_id, "abort")

    def results(self, campaign_id: int) -> list[str]:
        """Names of the campaign's result files (``summary.json``, ``iso230.json``, ...)."""
        return self._json("GET", f"/campaigns/{int(campaign_id)}/results")["results"]

    def result(self, campaign_id: int, name: str) -> bytes:
        """The bytes of one result file."""
        path = f"/campaigns/{int(campaign_id)}/results/{urllib.parse.quote(name)}"
        with self.request("GET", path) as r:
            return r.read()

    def summary(self, campaign_id: int) -> dict:
        """``summary.json``: per axis and phase measurements, times, recovery errors, time saved
        and the ISO 230-2 figures."""
        return json.loads(self.result(campaign_id, "summary.json"))

    def iso230(self, campaign_id: int) -> dict:
        """``iso230.json``: the ISO 230-2 figures per axis (full scan, measured, reconstructed)."""
        return json.loads(self.result(campaign_id, "iso230.json"))

    def samples(self, campaign_id: int, after: int = 0, limit: int = 10_000) -> dict:
        """One page of committed samples: ``{"id", "samples": [{"n", "sample"}], "next"}``."""
        q = urllib.parse.urlencode({"after": after, "limit": limit})
        return self._json("GET", f"/campaigns/{int(campaign_id)}/samples?{q}")

    def events(self, campaign_id: int, after: int = 0) -> Iterator[tuple[str, Optional[int], Any]]:
        """The campaign's server-sent events, ``(kind, id, data)``: the stored log after
        ``after``, then live events (``sample`` ones too); ends after ``finished``, at once for
        a campaign that is over. Blocks between events."""
        path = f"/campaigns/{int(campaign_id)}/events?after={int(after)}"
        resp = self.request("GET", path, accept="text/event-stream", timeout=None)
        kind, eid, data = "", None, []
        with resp:
            for raw in resp:
                line = raw.decode("utf-8").rstrip("\r\n")
                if not line:
                    if kind:
                        text = "\n".join(data)
                        yield kind, eid, (json.loads(text) if text else None)
                    kind, eid, data = "", None, []
                elif line.startswith("event:"):
                    kind = line[6:].strip()
                elif line.startswith("id:"):
                    eid = int(line[3:].strip())
                elif line.startswith("data:"):
                    data.append(line[5:].lstrip(" "))

    def wait(
        self,
        campaign_id: int,
        *,
        timeout: Optional[float] = None,
        poll_s: float = 0.2,
        on_status: Optional[Callable[[dict], Any]] = None,
        until: Callable[[dict], bool] = lambda st: st["state"] in FINAL_STATES,
    ) -> dict:
        """Polls the campaign's status every ``poll_s`` until ``until(status)`` (default: a
        final state); ``on_status`` sees each status. Returns the last one; ``TimeoutError``
        after ``timeout`` s."""
        t0 = time.monotonic()
        while True:
            st = self.status(campaign_id)
            if on_status is not None:
                on_status(st)
            if until(st):
                return st
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise TimeoutError(
                    f"campaign {campaign_id} still {st['state']} after {timeout} s "
                    f"({st['stored']}/{st['planned']} samples)"
                )
            time.sleep(poll_s)
