"""Drive the simulated C-863 with PI's own Python client (pipython 2.11.0.6, pure-Python gateways).

usage: scenarios.py tcp HOST:PORT | pty /path/to/tty

Run by tests/gcs_pipython.rs against `csmetro sim controller` at a high time scale. Every check
raises on failure; the last line printed is `PASS <transport>`.
"""
import sys
import time

from pipython import GCSError, pitools
from pipython.pidevice.gcscommands import GCSCommands
from pipython.pidevice.gcsmessages import GCSMessages


def gateway(kind, where):
    if kind == "tcp":
        from pipython.pidevice.interfaces.pisocket import PISocket

        host, port = where.rsplit(":", 1)
        return PISocket(host=host, port=int(port))
    if kind == "pty":
        from pipython.pidevice.interfaces.piserial import PISerial

        return PISerial(port=where, baudrate=115200)
    raise SystemExit(f"unknown transport {kind!r}")


def check(cond, what):
    if not cond:
        raise AssertionError(what)
    print("ok", what, flush=True)


def main():
    kind, where = sys.argv[1], sys.argv[2]
    with gateway(kind, where) as gw:
        dev = GCSCommands(GCSMessages(gw))

        # PI's start-up sequence on a fresh controller: HLP?, #24 + ERR? (10), #7, SAI?, SVO?,
        # FRF?, RON, FNL (refused with servo off) -> SVO 1 1 -> FNL, waiting on #7.
        pitools.startup(dev, refmodes=["FNL"])
        pitools.waitontarget(dev, "1", timeout=30)
        check(dev.qFRF("1")["1"] is True, "startup(FNL) referenced the axis")
        check(abs(dev.qPOS("1")["1"] - 0.0) < 1e-9, "FNL ends at the negative limit, 0 mm")

        idn = dev.qIDN()
        check("C-863.11" in idn.split(",")[1], f"qIDN names the C-863.11: {idn.strip()}")

        dev.SVO("1", True)
        check(dev.qSVO("1")["1"] is True, "SVO on")
        dev.FRF("1")
        pitools.waitonreferencing(dev, "1", timeout=30)
        check(dev.qFRF("1")["1"] is True, "FRF referenced")
        check(abs(dev.qPOS("1")["1"] - 7.5) < 1e-9, "FRF ends at the reference switch, 7.5 mm")

        dev.MOV("1", 12.25)
        check(dev.IsMoving("1")["1"] is True, "IsMoving right after MOV")
        check(dev.qONT("1")["1"] is False, "not on target while moving")
        pitools.waitontarget(dev, "1", timeout=30)
        check(dev.IsMoving("1")["1"] is False, "IsMoving false after the move")
        check(dev.qONT("1")["1"] is True, "qONT on target")
        check(abs(dev.qPOS("1")["1"] - 12.25) < 1e-9, "qPOS at the target")

        try:
            dev.MOV("1", 99)
        except GCSError as e:
            check(e.val == 7, f"out-of-range MOV raises GCSError 7: {e}")
        else:
            raise AssertionError("out-of-range MOV did not raise")
        check(abs(dev.qPOS("1")["1"] - 12.25) < 1e-9, "refused MOV did not move")
        check(abs(dev.qMOV("1")["1"] - 12.25) < 1e-9, "refused MOV kept the target")

        try:
            dev.SVO("2", True)
        except GCSError as e:
            check(e.val == 15, f"unknown axis raises GCSError 15: {e}")
        else:
            raise AssertionError("SVO on axis 2 did not raise")

        dev.MOV("1", 2.0)
        time.sleep(0.01)
        dev.HLT("1", noraise=True)
        deadline = time.time() + 5
        while dev.IsMoving("1")["1"] and time.time() < deadline:
            time.sleep(0.005)  # HLT decelerates
        check(dev.IsMoving("1")["1"] is False, "HLT stopped the move")
        check(dev.qPOS("1")["1"] > 2.0, "HLT stopped short of the target")
    print("PASS", kind, flush=True)


if __name__ == "__main__":
    main()
