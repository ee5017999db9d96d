"""Helpers of the tests: a real `csmetro serve` on 127.0.0.1:0 with its own configuration and
store (as the Rust tests' tests/common/mod.rs starts it), and small simulated campaigns.

The binary: ``CSMETRO_BIN``, else ``csmetro`` on PATH, else the repository's
target/debug/csmetro or target/release/csmetro. No binary is an error, not a skip: CI must run
these tests.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from csmetro_bluesky import Client

PACKAGE = Path(__file__).resolve().parents[1]
REPO = PACKAGE.parents[1]
MODELS = REPO / "config" / "sim"
DEMO = REPO / "config" / "campaigns" / "demo-sim.toml"


def csmetro_bin() -> str:
    env = os.environ.get("CSMETRO_BIN")
    if env:
        if not os.access(env, os.X_OK):
            pytest.fail(f"CSMETRO_BIN={env} is not an executable")
        return env
    on_path = shutil.which("csmetro")
    if on_path:
        return on_path
    for p in (REPO / "target" / "debug" / "csmetro", REPO / "target" / "release" / "csmetro"):
        if os.access(p, os.X_OK):
            return str(p)
    pytest.fail(
        "no csmetro binary: set CSMETRO_BIN, put csmetro on PATH or build it (cargo build)"
    )


class Service:
    """One `csmetro serve` process."""

    def __init__(self, root: Path, token: str | None = None):
        self.root = root
        self.token = token
        root.mkdir(parents=True, exist_ok=True)
        # Stage locks of this service only: other csmetro processes on the machine (other test
        # runs) use the same stage names.
        locks = root / "locks"
        locks.mkdir(exist_ok=True)
        config = root / "csmetro.toml"
        text = '[server]\nbind = "127.0.0.1:0"\n'
        if token:
            text += f'token = "{token}"\n'
        text += (
            '\n[storage]\ndb = "var/csmetro.db"\nresults_dir = "var/results"\n'
            '\n[log]\nfilter = "info"\n'
            # Submitted campaigns name their stage model (`ideal.toml`) among the shipped ones.
            f'\n[campaigns]\nbase_dir = "{MODELS}"\n'
        )
        config.write_text(text)
        env = dict(os.environ, CSMETRO_LOCK_DIR=str(locks))
        for k in ("RUST_LOG", "NOTIFY_SOCKET", "CSMETRO_SERVER", "CSMETRO_TOKEN"):
            env.pop(k, None)
        self.log_path = root / "serve.log"
        self._log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [csmetro_bin(), "serve", "--config", str(config)],
            stdout=subprocess.PIPE,
            stderr=self._log,
            env=env,
        )
        line = self.proc.stdout.readline().decode().strip()
        if not line.startswith("http://127.0.0.1:"):
            self.stop()
            raise RuntimeError(f"first stdout line {line!r}; log:\n{self.log()}")
        self.url = line
        # Keep draining stdout so the service never blocks on a full pipe.
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()

    def client(self, **kw) -> Client:
        kw.setdefault("token", self.token or "")
        return Client(self.url, **kw)

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


# Time scale of the campaigns a test pauses, stops or aborts while they run: 20 samples take
# ~3 s, several of the device's 0.2 s status polls. At 100 they took 0.6 s on an idle host and
# ended before the pause or stop the test sends after the 2nd sample (CI, 2026-12-06).
SLOW = 20


def campaign(
    name: str,
    stage: str,
    *,
    m: int = 8,
    time_scale: float = 1000,
    full_scan: bool = False,
    faults: str = "",
) -> str:
    """A campaign of ``2 * m`` CS targets on x (forward and backward) of a simulated stage on
    pseudo-terminals (the Rust tests' ``campaign()``), with the 41-point full scan if asked;
    ``faults``: keys of ``[hardware.sim.faults]``."""
    faults_section = f"\n[hardware.sim.faults]\n{faults}\n" if faults else ""
    return f"""[campaign]
name = "{name}"
stage = "{stage}"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "ideal.toml"
time_scale = {time_scale}
transport = "pty"
frame_time_s = 0.1
seed = 7
{faults_section}
[axes.x]
range_um = [0.0, 1000.0]
step_um = 25.0
other_at_um = 2100.0
m = {m}

[sampling]
design = "random"
seed = 3
full_scan = {"true" if full_scan else "false"}

[acquisition]
directions = ["forward", "backward"]
settle_s = 0.2

[outputs]
dir = "{name}-{{id}}"
"""


def wait_state(client: Client, cid: int, states, timeout: float = 60.0) -> dict:
    """Polls until the campaign is in one of ``states``."""
    states = {states} if isinstance(states, str) else set(states)
    return client.wait(cid, timeout=timeout, poll_s=0.05, until=lambda st: st["state"] in states)


def when(pred, timeout: float = 60.0, poll_s: float = 0.02) -> None:
    """Blocks until ``pred()``; fails the test after ``timeout`` s."""
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout:
            pytest.fail(f"timeout ({timeout} s) waiting for {pred}")
        time.sleep(poll_s)


class Docs:
    """Every document the RunEngine emitted, by kind."""

    def __init__(self):
        self.all = []

    def __call__(self, name, doc):
        self.all.append((name, doc))

    def __getitem__(self, kind):
        return [d for n, d in self.all if n == kind]


def pause_when(RE, dev, stored: int):
    """From another thread (as Ctrl-C does): pause the RunEngine once the campaign has stored
    that many samples."""

    def go():
        when(lambda: dev.stored.get() >= stored, timeout=60, poll_s=0.01)
        RE.request_pause()

    t = threading.Thread(target=go, daemon=True)
    t.start()
    return t


def held(client, cid: int) -> dict:
    """The campaign paused on the service, and staying so: no sample stored for a while (the
    point in flight when the pause came may still land)."""
    st = wait_state(client, cid, "paused", timeout=10)
    time.sleep(0.5)
    before = client.status(cid)["stored"]
    time.sleep(1.0)
    st = client.status(cid)
    assert st["state"] == "paused" and st["stored"] == before, st
    return st
