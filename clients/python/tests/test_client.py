"""The client against a live `csmetro serve` on the simulator."""

import pytest

from csmetro_bluesky import ApiError, Client
from support import SLOW, Service, campaign, wait_state


def test_health(client):
    h = client.health()
    assert h["status"] == "ok"
    assert h["version"]


def test_campaign_to_its_results(client, stage):
    st = client.submit(campaign("py-client", stage, full_scan=True), "client.toml")
    assert st["state"] in ("queued", "running")
    assert st["planned"] == 16 + 82  # 2 x m CS targets + the 41-point full scan both ways
    seen = []
    end = client.wait(st["id"], timeout=60, on_status=seen.append)
    assert end["state"] == "done", end
    assert end["stored"] == end["planned"] == 98
    assert [s["stored"] for s in seen] == sorted(s["stored"] for s in seen)

    names = client.results(st["id"])
    assert {"summary.json", "iso230.json", "report.html"} <= set(names)
    summary = client.summary(st["id"])
    assert summary["state"] == "done"
    assert summary["axes"][0]["phases"]["cs"]["measurements"] == 16
    iso = client.iso230(st["id"])
    assert iso["x"]["source"] == "full_scan"
    assert iso["x"]["full_scan"]["e_um"] == pytest.approx(summary["iso230"]["x"]["full_scan"]["e_um"])
    assert client.result(st["id"], "summary.txt").startswith(b"axis")

    # Every committed sample, by pages with the cursor (`n` counts in the whole store).
    got, after = [], 0
    while True:
        page = client.samples(st["id"], after=after, limit=40)
        if not page["samples"]:
            break
        got += [s["n"] for s in page["samples"]]
        assert page["next"] == got[-1]
        after = page["next"]
    assert len(got) == 98 and got == sorted(set(got))

    events = list(client.events(st["id"]))
    kinds = [k for k, _, _ in events]
    assert kinds[-1] == "finished" and events[-1][2]["data"]["state"] == "done"
    assert all(i is not None for _, i, _ in events)  # the stored log: every event has its id


def test_refusals_carry_the_reason(client):
    with pytest.raises(ApiError) as e:
        client.submit("[campaign]\nname = 'x'\n", "bad.toml")
    assert e.value.status == 400
    assert "bad.toml:" in e.value.message and "hardware" in e.value.message
    with pytest.raises(ApiError) as e:
        client.status(999_999)
    assert e.value.status == 404
    with pytest.raises(ApiError) as e:
        Client("http://127.0.0.1:9", timeout=2).health()
    assert e.value.status == 0 and "cannot reach" in e.value.message


def test_pause_resume_abort_name_the_operator(client, stage):
    cid = client.submit(campaign("py-control", stage, m=10, time_scale=SLOW))["id"]
    wait_state(client, cid, "running")
    st = client.pause(cid)
    assert st["state"] == "paused"
    assert 'operator "pytest"' in st["message"]
    assert client.resume(cid)["state"] == "running"
    client.abort(cid)
    end = wait_state(client, cid, ("aborted", "done"), timeout=30)
    assert end["state"] == "aborted", end
    with pytest.raises(ApiError) as e:  # not possible in that state
        client.resume(cid)
    assert e.value.status == 409
    by = {k: e["data"].get("by") for k, _, e in client.events(cid) if k in ("paused", "resumed")}
    assert 'operator "pytest"' in by["paused"] and 'operator "pytest"' in by["resumed"]


def test_token(tmp_path):
    s = Service(tmp_path / "tok", token="s3cret-token-of-the-test")
    try:
        with pytest.raises(ApiError) as e:
            Client(s.url, token="").health()
        assert e.value.status == 401
        with pytest.raises(ApiError) as e:
            Client(s.url, token="wrong").health()
        assert e.value.status == 401
        assert Client(s.url, token="s3cret-token-of-the-test").health()["status"] == "ok"
    finally:
        s.stop()
