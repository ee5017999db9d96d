"""The ophyd device under a real bluesky RunEngine against a live `csmetro serve` on the
simulator: documents, progress, pause/resume, failures, abort."""

import math
import threading

import bluesky.plans as bp
import bluesky.plan_stubs as bps
import pytest
from bluesky import RunEngine
from bluesky.utils import FailedStatus, RunEngineInterrupted

from csmetro_bluesky import AXIS_FIGURES, ApiError, CampaignError, CsmetroCampaign
from support import SLOW, Docs, Service, campaign, held, pause_when, wait_state, when


class Watched:
    """A waiting hook that records what status watchers hear (what a progress bar shows)."""

    def __init__(self):
        self.updates = []

    def __call__(self, statuses):
        for st in statuses or ():
            if hasattr(st, "watch") and not st.done:
                st.watch(lambda **kw: self.updates.append(kw))


@pytest.fixture
def RE():
    re = RunEngine({}, call_returns_result=True)
    re.docs = Docs()
    re.subscribe(re.docs)
    yield re
    if not re.state == "idle":
        re.halt()


def device(service, toml, **kw):
    return CsmetroCampaign(name="csm", server=service.url, campaign_toml=toml, operator="bluesky-test", **kw)


def test_count_holds_the_figures(service, client, stage, RE):
    dev = device(service, campaign("py-count", stage, full_scan=True))
    watched = Watched()
    RE.waiting_hook = watched
    result = RE(bp.count([dev], num=2))
    assert result.exit_status == "success"

    (desc,) = RE.docs["descriptor"]
    keys = desc["data_keys"]
    assert keys["csm_x_iso_e"]["units"] == "µm"
    assert keys["csm_x_acquisition_time"]["units"] == "s"
    assert keys["csm_time_saved"]["units"] == "%"
    assert keys["csm_x_iso_source"]["dtype"] == "string"
    assert not any(k.startswith("csm_y_") for k in keys)  # the campaign has no y axis
    assert set(desc["hints"]["csm"]["fields"]) == {"csm_x_iso_a", "csm_x_iso_e"}
    assert set(desc["configuration"]["csm"]["data"]) == {"csm_server", "csm_campaign_name", "csm_stage_name"}
    # read() and describe() agree
    assert set(dev.read()) == set(dev.describe())

    events = RE.docs["event"]
    assert len(events) == 2
    ids = [e["data"]["csm_campaign_id"] for e in events]
    assert ids[0] != ids[1]  # one campaign per trigger
    for ev, cid in zip(events, ids):
        data = ev["data"]
        assert data["csm_state"] == "done"
        assert data["csm_stored"] == data["csm_planned"] == 98
        # The ISO 230-2 figures are the service's own.
        iso = client.iso230(cid)["x"]
        assert data["csm_x_iso_source"] == iso["source"] == "full_scan"
        for letter in "aebm":
            assert data[f"csm_x_iso_{letter}"] == pytest.approx(iso["full_scan"][f"{letter}_um"])
        assert math.isnan(data["csm_x_iso_r"])  # one cycle: no repeatability
        # The reconstruction summary.
        axis = client.summary(cid)["axes"][0]
        assert data["csm_x_measurements"] == data["csm_measurements"] == 16
        assert data["csm_x_full_measurements"] == 82
        assert data["csm_x_time_saved"] == pytest.approx(axis["acquisition_saved_pct"])
        worst = max(c["cs_vs_full"]["max_abs_um"] for c in axis["components"])
        assert data["csm_x_error_vs_full_max"] == pytest.approx(worst)
        assert 0 < data["csm_x_cv_error"] < 1
        assert 0 < data["csm_x_error_vs_truth_mean"] <= data["csm_x_error_vs_truth_max"]
        assert all(f"csm_x_{f.attr}" in data for f in AXIS_FIGURES)

    # What a progress bar heard: samples counting up to the plan, ending with nothing left.
    counts = [u for u in watched.updates if u.get("target")]
    assert counts and all(u["name"] == "csm" and u["unit"] == "samples" for u in counts)
    assert counts[-1]["current"] == counts[-1]["target"] == 98
    assert counts[-1]["fraction"] == 0.0
    assert any(0 < u["current"] < 98 for u in counts)


def test_trigger_outside_a_run_engine(service, stage):
    dev = device(service, campaign("py-direct", stage))
    st = dev.trigger()
    st.wait(60)
    assert st.success and st.campaign_id == dev.campaign_id.get()
    r = dev.read()
    assert r["csm_state"]["value"] == "done"
    assert r["csm_x_iso_source"]["value"] == "reconstructed"  # no full scan, no cycles
    assert r["csm_x_iso_e"]["value"] > 0
    assert math.isnan(r["csm_x_time_saved"]["value"])  # nothing to compare with
    assert dev.last_summary["state"] == "done"


def test_refused_campaign_fails_the_status(service, RE):
    bad = campaign("py-bad", "py-bad").replace("m = 8", "m = -3")
    dev = device(service, bad, file_name="bad.toml")
    with pytest.raises(FailedStatus) as e:
        RE(bp.count([dev]))
    err = e.value.__cause__
    assert isinstance(err, CampaignError) and err.state == "refused"
    assert "bad.toml:" in err.message and "axes.x.m" in err.message, err.message
    assert err.campaign_id is None
    assert RE.docs["stop"][0]["exit_status"] == "fail"


def test_failing_campaign_fails_the_status_with_the_reason(service, stage, RE):
    # Every reply of the simulated controllers is an error: the service stops the campaign.
    dev = device(service, campaign("py-fault", stage, faults="seed = 1\nerror_rate = 1.0"))
    with pytest.raises(FailedStatus) as e:
        RE(bp.count([dev]))
    err = e.value.__cause__
    assert isinstance(err, CampaignError)
    assert err.state in ("interrupted", "failed")
    assert "controller error" in err.message, err.message
    assert err.campaign_id == dev.campaign_id.get() > 0
    assert dev.state.get() == err.state


def test_pause_resume(service, client, stage, RE):
    dev = device(service, campaign("py-pause", stage, m=10, time_scale=SLOW))
    pause_when(RE, dev, 2)
    with pytest.raises(RunEngineInterrupted):
        RE(bp.count([dev]))
    assert RE.state == "paused"
    cid = dev.campaign_id.get()
    st = held(client, cid)
    assert 'operator "bluesky-test"' in st["message"]
    assert st["stored"] < st["planned"]

    result = RE.resume()  # the plan replays its trigger: the same campaign continues
    assert result.exit_status == "success"
    assert client.status(cid)["state"] == "done"
    (ev,) = RE.docs["event"]
    assert ev["data"]["csm_campaign_id"] == cid
    assert ev["data"]["csm_state"] == "done"
    assert ev["data"]["csm_x_iso_e"] > 0
    # Nothing was submitted twice.
    assert [c["id"] for c in client.campaigns() if c["stage"] == stage] == [cid]


def test_campaign_ending_during_the_pause_is_not_run_twice(service, client, stage, RE):
    dev = device(service, campaign("py-pause-end", stage, m=10, time_scale=SLOW))
    pause_when(RE, dev, 2)
    with pytest.raises(RunEngineInterrupted):
        RE(bp.count([dev]))
    cid = dev.campaign_id.get()
    wait_state(client, cid, "paused", timeout=10)
    # The operator resumes it on the service (the web page) while the RunEngine stays paused.
    client.resume(cid)
    wait_state(client, cid, "done", timeout=60)
    assert RE.resume().exit_status == "success"  # the replayed trigger: the finished campaign
    (ev,) = RE.docs["event"]
    assert ev["data"]["csm_campaign_id"] == cid and ev["data"]["csm_state"] == "done"
    assert [c["id"] for c in client.campaigns() if c["stage"] == stage] == [cid]


def test_abort_while_paused_aborts_the_campaign(service, client, stage, RE):
    dev = device(service, campaign("py-abort", stage, m=10, time_scale=SLOW))
    pause_when(RE, dev, 2)
    with pytest.raises(RunEngineInterrupted):
        RE(bp.count([dev]))
    cid = dev.campaign_id.get()
    wait_state(client, cid, "paused", timeout=10)
    result = RE.abort("enough")
    assert result.exit_status == "abort"
    # unstage() aborted the campaign and waited for its end.
    assert client.status(cid)["state"] == "aborted"
    assert RE.docs["stop"][0]["exit_status"] == "abort"
    assert RE.docs["event"] == []
    # The device runs the next plan with a new campaign (here: another file).
    dev.campaign_toml = campaign("py-abort-next", stage, m=5)
    assert RE(bp.count([dev])).exit_status == "success"
    (ev,) = RE.docs["event"]
    assert ev["data"]["csm_campaign_id"] != cid and ev["data"]["csm_state"] == "done"
    assert dev.campaign_name.get() == "py-abort-next"


def test_halt_while_paused_aborts_the_campaign(service, client, stage, RE):
    dev = device(service, campaign("py-halt", stage, m=10, time_scale=SLOW))
    pause_when(RE, dev, 2)
    with pytest.raises(RunEngineInterrupted):
        RE(bp.count([dev]))
    cid = dev.campaign_id.get()
    wait_state(client, cid, "paused", timeout=10)
    RE.halt()  # no cleanup by the plan; the RunEngine still unstages what is staged
    assert client.status(cid)["state"] == "aborted"
    assert RE.docs["stop"][0]["exit_status"] == "abort"


def test_stop_while_running_aborts_the_campaign(service, client, stage, RE):
    dev = device(service, campaign("py-stop", stage, m=10, time_scale=SLOW))

    def stop():
        when(lambda: dev.stored.get() >= 2, timeout=60, poll_s=0.01)
        RE.stop()

    threading.Thread(target=stop, daemon=True).start()
    with pytest.raises(RunEngineInterrupted):  # how RE() ends when another thread stops it
        RE(bp.count([dev]))
    cid = dev.campaign_id.get()
    st = client.status(cid)
    assert st["state"] == "aborted" and st["stored"] < st["planned"], st
    assert RE.docs["stop"][0]["exit_status"] == "success"  # RE.stop(): a successful end


def test_plan_exception_aborts_the_campaign(service, client, stage, RE):
    # Slow enough (referencing alone takes seconds) to be running when the plan gives up.
    dev = device(service, campaign("py-raise", stage, m=10, time_scale=5))

    def plan():
        yield from bps.stage(dev)
        yield from bps.open_run()
        yield from bps.trigger(dev, group="c")  # not waited for
        yield from bps.sleep(0.5)
        raise RuntimeError("the plan gave up")

    with pytest.raises(RuntimeError, match="gave up"):
        RE(plan())
    cid = dev.campaign_id.get()
    st = client.status(cid)
    assert st["state"] == "aborted" and st["stored"] < st["planned"], st


def test_token(tmp_path, RE):
    s = Service(tmp_path / "tok", token="the-token-of-the-device-test")
    try:
        toml = campaign("py-token", "py-token")
        dev = CsmetroCampaign(name="csm", server=s.url, campaign_toml=toml, token="wrong-token")
        with pytest.raises(ApiError) as e:  # stage() asks the service before the run opens
            RE(bp.count([dev]))
        assert e.value.status == 401
        assert RE.docs["start"] == []
        dev = CsmetroCampaign(
            name="csm", server=s.url, campaign_toml=toml, token="the-token-of-the-device-test"
        )
        assert RE(bp.count([dev])).exit_status == "success"
        assert RE.docs["event"][0]["data"]["csm_state"] == "done"
    finally:
        s.stop()
