"""The demo campaign (config/campaigns/demo-sim.toml: X and Y, forward and backward, 600 and 300
random measurements on the paper-like simulated stage) driven end to end by a bluesky plan
through the ophyd device, with a RunEngine pause in the middle: campaign paused → resume → done.

The demo's 5 µm full scan (5484 more measurements, about two minutes of a debug build) is left
out to keep the suite within three minutes; ``CSMETRO_DEMO_FULL_SCAN=1`` keeps it.
"""

import os
import re

import bluesky.plans as bp
import pytest
from bluesky import RunEngine
from bluesky.utils import ProgressBarManager, RunEngineInterrupted

from csmetro_bluesky import CsmetroCampaign
from support import DEMO, Docs, held, pause_when


def demo_toml() -> tuple[str, bool]:
    text = DEMO.read_text()
    full = os.environ.get("CSMETRO_DEMO_FULL_SCAN") == "1"
    if not full:
        text, n = re.subn(r"(?m)^full_scan = true", "full_scan = false", text)
        assert n == 1, "demo-sim.toml changed: no `full_scan = true` line"
    return text, full


def test_demo_campaign_with_pause(service, client):
    text, full = demo_toml()
    dev = CsmetroCampaign(
        name="demo", server=service.url, campaign_toml=text, file_name="demo-sim.toml"
    )
    assert dev.axes == ("x", "y")
    RE = RunEngine({}, call_returns_result=True)
    docs = Docs()
    RE.subscribe(docs)
    RE.waiting_hook = ProgressBarManager()  # bluesky's own progress bar on the status

    pause_when(RE, dev, 100)
    with pytest.raises(RunEngineInterrupted):
        RE(bp.count([dev], md={"purpose": "csmetro demo"}))
    cid = dev.campaign_id.get()
    st = held(client, cid)
    assert 100 <= st["stored"] < st["planned"] == (6384 if full else 900)

    result = RE.resume()
    assert result.exit_status == "success", result
    st = client.status(cid)
    assert st["state"] == "done" and st["stored"] == st["planned"]

    (start,) = docs["start"]
    assert start["purpose"] == "csmetro demo"
    (ev,) = docs["event"]
    data = ev["data"]
    assert data["demo_campaign_id"] == cid and data["demo_state"] == "done"
    assert data["demo_measurements"] == 900
    assert data["demo_x_measurements"] == 600 and data["demo_y_measurements"] == 300
    summary = client.summary(cid)
    for axis in ("x", "y"):
        iso = summary["iso230"][axis]
        assert data[f"demo_{axis}_iso_source"] == iso["source"]
        assert iso["source"] == ("full_scan" if full else "reconstructed")
        for letter in "aebm":
            assert data[f"demo_{axis}_iso_{letter}"] == pytest.approx(iso[iso["source"]][f"{letter}_um"])
        # The paper-like stage: micrometres of error, recovered to a fraction of a micrometre.
        assert 1.0 < data[f"demo_{axis}_iso_e"] < 20.0
        assert 0 < data[f"demo_{axis}_error_vs_truth_mean"] < 0.5
    (stop,) = docs["stop"]
    assert stop["exit_status"] == "success"
