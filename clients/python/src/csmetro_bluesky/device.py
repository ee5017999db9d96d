"""An ophyd device that runs one csmetro characterisation campaign per ``trigger()``.

``trigger()`` submits the campaign to ``csmetro serve`` and returns a status that a background
thread finishes when the campaign ends: ``done`` → success, with the figures of its
``summary.json`` in the device's signals; ``failed``, ``aborted`` or ``interrupted`` → the status
fails with :class:`CampaignError` carrying the service's message; a campaign the service refuses
(HTTP 400: the file's line and key) fails the status at once. While it runs, the status reports
stored/planned samples to its watchers (bluesky's progress bar).

The RunEngine's interruptions map onto the campaign:

* ``RE.request_pause()`` (Ctrl-C) → ``pause()`` → the campaign holds between two points
  (``paused`` on the service);
* ``RE.resume()`` → ``resume()`` → it continues. The RunEngine replays its plan from the last
  checkpoint and so calls ``trigger()`` again: that returns a status of the same campaign
  (also when it ended during the pause), nothing is submitted twice;
* ``RE.abort()``, ``RE.stop()``, ``RE.halt()`` (and an exception in the plan) → ``unstage()``
  with the campaign unfinished → ``abort`` on the service (motion stops; the campaign ends
  ``aborted``); ``stop()`` does the same.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import tomllib
from typing import Any, Optional

from ophyd import Component as Cpt
from ophyd import Device, DeviceStatus, Kind, Signal

from . import figures
from .client import FINAL_STATES, ApiError, Client

logger = logging.getLogger(__name__)

#: The axes a characterisation can have; a campaign's ``[axes.*]`` says which it has.
AXES = ("x", "y")


class CampaignError(RuntimeError):
    """A campaign that did not end ``done`` (or was refused): ``state`` is the service's state
    (``failed``, ``aborted``, ``interrupted``; ``refused`` for an HTTP error at submission),
    ``message`` its reason, ``campaign_id`` its id (``None`` when refused)."""

    def __init__(self, state: str, message: str, campaign_id: Optional[int] = None):
        self.state = state
        self.message = message
        self.campaign_id = campaign_id
        which = f"campaign {campaign_id}" if campaign_id is not None else "campaign"
        super().__init__(f"{which} {state}: {message}" if message else f"{which} {state}")


class FigureSignal(Signal):
    """A soft signal whose ``describe()`` gives its units."""

    def __init__(self, *args, units: str = "", precision: Optional[int] = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.units = units
        self.precision = precision

    def describe(self):
        d = super().describe()
        if self.units:
            d[self.name]["units"] = self.units
        if self.precision is not None:
            d[self.name]["precision"] = self.precision
        return d


def _precision(f: figures.Figure) -> Optional[int]:
    if f.dtype is not float:
        return None
    return {"µm": 4, "s": 2, "%": 2}.get(f.units)


def _component(f: figures.Figure, kind: str = "normal") -> Cpt:
    if f.dtype is str:
        return Cpt(Signal, value="", kind=kind, doc=f.doc)
    return Cpt(
        FigureSignal,
        value=figures.unset(f),
        units=f.units,
        precision=_precision(f),
        kind=kind,
        doc=f.doc,
    )


#: Figures shown by default (``hints``): the ISO 230-2 accuracy and systematic deviation.
_HINTED = {"iso_a", "iso_e"}

AxisFigures = type(
    "AxisFigures",
    (Device,),
    {
        "__doc__": "The figures of one characterised axis (see csmetro_bluesky.figures).",
        **{
            f.attr: _component(f, "hinted" if f.attr in _HINTED else "normal")
            for f in figures.AXIS_FIGURES
        },
    },
)


class CampaignStatus(DeviceStatus):
    """The status of one campaign's ``trigger()``: watchers (progress bars) get ``name``,
    ``current`` (stored samples), ``initial`` (0), ``target`` (planned samples),
    ``unit`` ("samples"), ``fraction`` (the fraction *remaining*, ophyd's convention: 1 → 0),
    ``time_elapsed`` and ``time_remaining`` (the service's ETA, s)."""

    def __init__(self, device, **kwargs):
        self._progress: dict[str, Any] = {}
        self.campaign_id: Optional[int] = None
        super().__init__(device, call_stop_on_failure=False, **kwargs)

    def watch(self, func):
        self._watchers.append(func)
        func(**self._progress_kwargs())

    def _settled(self):
        # DeviceStatus tells its watchers only `fraction=0.0` at the end; keep the counts so a
        # progress bar ends full rather than "no progress bar available".
        if self._progress:
            self._progress["fraction"] = 0.0
            self._progress["time_remaining"] = 0.0
        for w in list(self._watchers):
            try:
                w(**self._progress_kwargs())
            except Exception:
                logger.exception("status watcher failed")

    def _progress_kwargs(self) -> dict[str, Any]:
        kw = {"name": self.device.name}
        kw.update(self._progress)
        return kw

    def _update(self, st: dict) -> None:
        planned = int(st.get("planned") or 0)
        stored = int(st.get("stored") or 0)
        self._progress = {
            "current": stored,
            "initial": 0,
            "target": planned,
            "unit": "samples",
            "precision": 0,
            "fraction": (1.0 - stored / planned) if planned else None,
            "time_elapsed": st.get("elapsed_s"),
            "time_remaining": st.get("eta_s"),
        }
        for w in list(self._watchers):
            try:
                w(**self._progress_kwargs())
            except Exception:  # a broken progress bar must not stop the campaign's follower
                logger.exception("status watcher failed")


class _Run:
    """One submitted campaign, followed until it ends."""

    def __init__(self, campaign_id: int):
        self.id = campaign_id
        self.statuses: list[CampaignStatus] = []
        self.finished = threading.Event()
        self.outcome: Optional[BaseException] = None
        self.paused_by_us = False
        #: The RunEngine paused while this campaign ran: its replay of the plan will trigger
        #: again, and that trigger is this campaign's even if it ended during the pause.
        self.replay = False
        self.last: dict = {}


class CsmetroCampaign(Device):
    """A characterisation campaign on ``csmetro serve``, one run per ``trigger()``.

    Parameters
    ----------
    name : the device's name (prefix of its data keys).
    server : the service's URL (default ``CSMETRO_SERVER``, else http://127.0.0.1:8463).
    campaign_toml : the campaign file's text; or ``campaign_file``: a path to read it from.
    token : bearer token (default ``CSMETRO_TOKEN``); operator : the name the service's audit
        trail records (``X-Operator``; default ``CSMETRO_OPERATOR``, else "bluesky").
    poll_s : status polling period, s. timeout : fail the trigger's status after that many s
        (default: none). lost_after_s : fail it after the service has not answered for that
        long (default 120 s; the service resumes campaigns when it restarts).
    """

    campaign_id = Cpt(Signal, value=0, kind="normal", doc="the service's id of the campaign")
    state = Cpt(Signal, value="", kind="normal", doc="its final state (done, failed, ...)")
    message = Cpt(Signal, value="", kind="normal", doc="the service's message (reason of a failure)")
    stored = Cpt(FigureSignal, value=0, units="samples", kind="normal", doc="samples stored")
    planned = Cpt(FigureSignal, value=0, units="samples", kind="normal", doc="samples planned")
    measurements = _component(figures.CAMPAIGN_FIGURES[0])
    acquisition_time = _component(figures.CAMPAIGN_FIGURES[1])
    time_saved = _component(figures.CAMPAIGN_FIGURES[2])
    measurements_saved = _component(figures.CAMPAIGN_FIGURES[3])
    x = Cpt(AxisFigures, "", kind="normal", doc="figures of the x axis")
    y = Cpt(AxisFigures, "", kind="normal", doc="figures of the y axis")
    progress = Cpt(
        FigureSignal, value=0.0, units="", kind="omitted", doc="stored / planned, live (0..1)"
    )
    server = Cpt(Signal, value="", kind="config", doc="the service's URL")
    campaign_name = Cpt(Signal, value="", kind="config", doc="[campaign] name of the file")
    stage_name = Cpt(Signal, value="", kind="config", doc="[campaign] stage of the file")

    def __init__(
        self,
        prefix: str = "",
        *,
        name: str,
        server: Optional[str] = None,
        campaign_toml: Optional[str] = None,
        campaign_file: Optional[str] = None,
        file_name: Optional[str] = None,
        token: Optional[str] = None,
        operator: Optional[str] = None,
        poll_s: float = 0.2,
        timeout: Optional[float] = None,
        lost_after_s: float = 120.0,
        client: Optional[Client] = None,
        **kwargs,
    ):
        super().__init__(prefix, name=name, **kwargs)
        if client is None:
            client = Client(
                server,
                token=token,
                operator=operator or os.environ.get("CSMETRO_OPERATOR") or "bluesky",
            )
        self.client = client
        self.poll_s = poll_s
        self.timeout = timeout
        self.lost_after_s = lost_after_s
        #: How long ``unstage()``/``stop()`` wait for an aborted campaign to end, s.
        self.abort_wait_s = 15.0
        #: After an abort by the plan's cleanup, how long the trigger's status stays pending
        #: past the campaign's end (see ``_abort_unfinished``), s.
        self.orphan_grace_s = 2.0
        self._lock = threading.RLock()
        self._run: Optional[_Run] = None
        #: The last finished campaign's ``summary.json`` (everything the signals flatten).
        self.last_summary: Optional[dict] = None
        self.server.put(self.client.server)
        self._file_name = file_name
        if campaign_file is not None:
            with open(campaign_file, encoding="utf-8") as f:
                campaign_toml = f.read()
            self._file_name = file_name or str(campaign_file).replace("\\", "/").rsplit("/", 1)[-1]
        self.campaign_toml = campaign_toml

    # -- the campaign file --------------------------------------------------------------------

    @property
    def campaign_toml(self) -> Optional[str]:
        """The campaign file's text; setting it (between runs) re-reads which axes it has."""
        return self._toml

    @campaign_toml.setter
    def campaign_toml(self, text: Optional[str]) -> None:
        self._toml = text
        axes: tuple[str, ...] = AXES
        name = stage = ""
        if text is not None:
            try:
                spec = tomllib.loads(text)
            except tomllib.TOMLDecodeError:
                spec = None  # the service says what is wrong, at trigger()
            if isinstance(spec, dict):
                camp = spec.get("campaign") if isinstance(spec.get("campaign"), dict) else {}
                name, stage = str(camp.get("name", "")), str(camp.get("stage", ""))
                if isinstance(spec.get("axes"), dict):
                    axes = tuple(a for a in AXES if a in spec["axes"])
                elif "map" in spec:
                    axes = ()  # an XY map: no per-axis figures
        self.axes = axes
        self.campaign_name.put(name)
        self.stage_name.put(stage)
        # Only the campaign's axes are read (the others would be NaN columns).
        for a in AXES:
            getattr(self, a).kind = Kind.normal if a in axes else Kind.omitted

    # -- bluesky interface --------------------------------------------------------------------

    def stage(self):
        # Fail before the run opens when the service cannot be reached or refuses the token.
        self.client.health()
        return super().stage()

    def unstage(self):
        self._abort_unfinished("unstaged", detach=True)
        if self._run is not None:
            self._run.replay = False  # the plan is over: the next trigger is a new campaign
        return super().unstage()

    def stop(self, *, success: bool = False):
        self._abort_unfinished("stopped", detach=False)
        super().stop(success=success)

    def pause(self):
        run = self._run
        if run is not None and not run.finished.is_set():
            run.replay = True
            try:
                self.client.pause(run.id)
                run.paused_by_us = True
                logger.info("%s: campaign %s paused", self.name, run.id)
            except ApiError as e:
                # 409: it ended (or is already held) meanwhile; the follower sees which.
                logger.warning("%s: pause of campaign %s: %s", self.name, run.id, e)
        super().pause()

    def resume(self):
        run = self._run
        if run is not None and run.paused_by_us and not run.finished.is_set():
            try:
                self.client.resume(run.id)
                logger.info("%s: campaign %s resumed", self.name, run.id)
            except ApiError as e:
                logger.warning("%s: resume of campaign %s: %s", self.name, run.id, e)
            run.paused_by_us = False
        super().resume()

    def trigger(self) -> CampaignStatus:
        with self._lock:
            st = CampaignStatus(self, timeout=self.timeout)
            run = self._run
            if run is not None and (run.replay or not run.finished.is_set()):
                # The RunEngine replays the plan from its last checkpoint after a pause: this is
                # the campaign already under way (or that ended during the pause), not a new one.
                run.replay = False
                self._attach(run, st)
                return st
            self._clear()
            if self._toml is None:
                self._fail(st, CampaignError("refused", "no campaign file given (campaign_toml)"))
                return st
            try:
                s = self.client.submit(self._toml, self._file_name)
            except ApiError as e:
                state = "refused" if e.status else "unreachable"
                self.state.put(state)
                self.message.put(e.message)
                self._fail(st, CampaignError(state, e.message))
                return st
            run = _Run(int(s["id"]))
            self._run = run
            self._show(run, s)
            self._attach(run, st)
            threading.Thread(
                target=self._follow, args=(run,), name=f"{self.name}-campaign-{run.id}", daemon=True
            ).start()
            return st

    # -- internals ----------------------------------------------------------------------------

    @staticmethod
    def _fail(st: CampaignStatus, exc: BaseException) -> None:
        try:
            st.set_exception(exc)
        except Exception:  # already timed out
            pass

    def _attach(self, run: _Run, st: CampaignStatus) -> None:
        st.campaign_id = run.id
        with self._lock:
            if run.finished.is_set():
                if run.outcome is None:
                    st.set_finished()
                else:
                    self._fail(st, run.outcome)
                return
            run.statuses.append(st)
            if run.last:
                st._update(run.last)

    def _clear(self) -> None:
        self.last_summary = None
        for sig in ("campaign_id", "stored", "planned"):
            getattr(self, sig).put(0)
        self.state.put("")
        self.message.put("")
        self.progress.put(0.0)
        for k, v in figures.empty_campaign().items():
            getattr(self, k).put(v)
        for a in AXES:
            dev = getattr(self, a)
            for k, v in figures.empty_axis().items():
                getattr(dev, k).put(v)

    def _show(self, run: _Run, st: dict) -> None:
        run.last = st
        self.campaign_id.put(run.id)
        self.state.put(st.get("state") or "")
        self.message.put(st.get("message") or "")
        planned, stored = int(st.get("planned") or 0), int(st.get("stored") or 0)
        self.planned.put(planned)
        self.stored.put(stored)
        self.progress.put(stored / planned if planned else 0.0)

    def _fill(self, summary: dict, iso230: Optional[dict]) -> None:
        self.last_summary = summary
        for k, v in figures.campaign_figures(summary).items():
            getattr(self, k).put(v)
        for a in self.axes:
            dev = getattr(self, a)
            for k, v in figures.axis_figures(summary, a, iso230).items():
                getattr(dev, k).put(v)

    def _follow(self, run: _Run) -> None:
        """Polls the campaign until it ends; then fills the figures and finishes the statuses."""
        outcome: Optional[BaseException] = None
        last_ok = time.monotonic()
        while True:
            try:
                st = self.client.status(run.id)
                last_ok = time.monotonic()
            except ApiError as e:
                if e.status == 0 and time.monotonic() - last_ok < self.lost_after_s:
                    time.sleep(max(self.poll_s, 1.0))
                    continue
                outcome = CampaignError("lost", str(e), run.id)
                break
            with self._lock:
                self._show(run, st)
                for s in list(run.statuses):
                    s._update(st)
            if st["state"] in FINAL_STATES:
                if st["state"] != "done":
                    outcome = CampaignError(st["state"], st.get("message") or "", run.id)
                break
            time.sleep(self.poll_s)
        if outcome is None:
            try:
                summary = self.client.summary(run.id)
                iso = None
                if "iso230" not in summary and "iso230.json" in self.client.results(run.id):
                    iso = self.client.iso230(run.id)
                self._fill(summary, iso)
            except (ApiError, ValueError) as e:
                outcome = CampaignError("done", f"but its results could not be read: {e}", run.id)
        with self._lock:
            run.outcome = outcome
            run.finished.set()
            statuses, run.statuses = run.statuses, []
        for s in statuses:
            if s.done:
                continue
            if outcome is None:
                s.set_finished()
            else:
                self._fail(s, outcome)

    def _abort_unfinished(self, why: str, *, detach: bool) -> None:
        """Aborts the campaign if it is unfinished and waits (briefly) for its end.

        ``detach``: the caller is the plan's cleanup (``unstage`` under ``RE.abort()``,
        ``RE.stop()``, an exception): the RunEngine still holds the trigger's status, and a status
        failing now would turn that cleanup into a failed run (bluesky throws a failed status into
        the plan until the run is over). Those statuses are failed a moment after the campaign's
        end instead, once the RunEngine has let the run go.
        """
        run = self._run
        if run is None or run.finished.is_set():
            return
        orphans: list[CampaignStatus] = []
        if detach:
            with self._lock:
                orphans, run.statuses = run.statuses, []
        logger.info("%s %s: aborting campaign %s", self.name, why, run.id)
        try:
            self.client.abort(run.id)
        except ApiError as e:
            logger.warning("%s: abort of campaign %s: %s", self.name, run.id, e)
        # Motion has stopped once the service says so: wait for it, briefly.
        run.finished.wait(self.abort_wait_s)
        if orphans:

            def settle():
                run.finished.wait()
                time.sleep(self.orphan_grace_s)
                for st in orphans:
                    if st.done:
                        continue
                    if run.outcome is None:
                        st.set_finished()
                    else:
                        self._fail(st, run.outcome)

            threading.Thread(target=settle, name=f"{self.name}-orphans-{run.id}", daemon=True).start()
