"""The OPC UA server of ``online-backlash opcua``: the fleet's gauges, following the store, with state events.

:class:`PlantServer` builds the model of :mod:`.model` over an asyncua ``Server`` secured as
:mod:`.security` says, then polls the store every ``poll_s`` seconds (the store is opened
read-only; a poll runs in a worker thread, so the server keeps answering meanwhile). A gearbox's
report (:func:`~online_backlash.history.report.wear_report`, the figures of ``history --json``) is
read again when the gearbox's stored revision or levels moved (every ``track`` commit moves the
revision) and at least every :data:`RECHECK_S` seconds (the state turns ``unknown`` as the latest
estimate ages). Gearboxes new to the store get their object as they appear.

A state change raises an event of the alarm type ``BacklashStateAlarmType`` (an ``OffNormalAlarmType``,
OPC UA Part 9) with the fields ``Gearbox``, ``State``, ``PlayArcmin``, a ``Message``, a ``Severity``
(ok 100, unknown 300, warning 600, alarm 900), ``ActiveState/Id`` (true in warning and alarm) and
``SourceName`` the gearbox id; it is sent both from the gearbox's object and from the ``Server``
object, where most clients subscribe to the events of a whole server. States found when the server
starts raise no event.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua
from sqlalchemy.exc import SQLAlchemyError

from ..errors import BacklashError
from ..history.gauges import GearboxGauges, gearbox_gauges
from ..history.report import wear_report
from ..history.store import HistoryStore
from .model import GearboxObject, node_id, utc
from .security import ReadOnlyUsers, secure
from .settings import OpcuaSecurity

#: The namespace of the model's nodes.
NAMESPACE_URI = "urn:online-backlash:gearboxes"
#: Seconds after which a gearbox's report is read again even if nothing was stored (the state ages).
RECHECK_S = 60.0
#: Severity of each state in the state events (1..1000).
SEVERITY = {"ok": 100, "unknown": 300, "warning": 600, "alarm": 900}


@dataclass
class _Seen:
    """What the server last read of a gearbox: the stored record's key, its gauges, when."""

    key: tuple
    gauges: GearboxGauges
    read_at: float


@dataclass
class FleetReader:
    """The gauges of every gearbox in ``store``, each read again only when its stored record moved or aged."""

    store: HistoryStore
    max_age_h: float
    seen: dict[str, _Seen] = field(default_factory=dict)

    def read(self) -> list[GearboxGauges]:
        now = time.time()
        fleet = []
        for gearbox_id in self.store.gearbox_ids():
            gearbox = self.store.gearbox(gearbox_id)
            key = (gearbox.revision, gearbox.warn_arcmin, gearbox.limit_arcmin)
            last = self.seen.get(gearbox_id)
            if last is None or last.key != key or now - last.read_at >= RECHECK_S:
                report = wear_report(self.store, gearbox_id, max_age_h=self.max_age_h, now_unix_s=now)
                last = self.seen[gearbox_id] = _Seen(key, gearbox_gauges(report), now)
            fleet.append(last.gauges)
        return fleet


class PlantServer:
    """The fleet of ``store`` served over OPC UA at ``endpoint`` (``opc.tcp://HOST:PORT[/PATH]``).

    Parameters
    ----------
    store : HistoryStore
        The history store, opened read-only.
    endpoint : str
        Where to listen.
    security : OpcuaSecurity
        Message security, certificates and users (:mod:`.security`).
    poll_s : float
        Seconds between two reads of the store.
    max_age_h : float
        Calendar hours after which a gearbox's latest estimate no longer counts (its state is ``unknown``).
    on_event : callable, optional
        Called with each state change's gauges after its event went out (for a log line).
    on_error : callable, optional
        Called with the reason when reading the store starts failing, and with None when it works again.

    A read of the store that fails (a database restarting, a network gone) stops nothing: every
    variable keeps its value with the status ``UncertainLastUsableValue`` until a read works again.
    """

    def __init__(
        self,
        store: HistoryStore,
        endpoint: str,
        security: OpcuaSecurity,
        poll_s: float = 2.0,
        max_age_h: float = 168.0,
        on_event: Callable[[GearboxGauges], None] | None = None,
        on_error: Callable[[str | None], None] | None = None,
    ) -> None:
        self.reader = FleetReader(store, max_age_h)
        self.endpoint = endpoint
        self.security = security
        self.poll_s = poll_s
        self.on_event = on_event
        self.on_error = on_error
        self.objects: dict[str, GearboxObject] = {}
        self.states: dict[str, str] = {}
        self.certificate = ""
        #: Why the last read of the store failed (None: it did not); the values shown are then uncertain.
        self.read_error: str | None = None
        self._events: dict[str, Any] = {}
        self._server: Server | None = None

    async def start(self) -> None:
        """Build the address space from the store as it is now and listen (no events for the states found)."""
        password = self.security.check()
        server = Server(user_manager=ReadOnlyUsers(self.security.user, password, self.security.allow_anonymous))
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name("online-backlash")
        self.certificate = await secure(server, self.security)
        idx = await server.register_namespace(NAMESPACE_URI)
        self._idx = idx
        self._folder = await server.nodes.objects.add_folder(
            node_id(idx, "Gearboxes"), ua.QualifiedName("Gearboxes", idx)
        )
        self._alarm_type = await server.create_custom_event_type(
            idx,
            "BacklashStateAlarmType",
            ua.ObjectIds.OffNormalAlarmType,
            [
                ("Gearbox", ua.VariantType.String),
                ("State", ua.VariantType.String),
                ("PlayArcmin", ua.VariantType.Double),
            ],
        )
        self._server = server
        self._server_events = await server.get_event_generator(self._alarm_type, ua.ObjectIds.Server)
        await self._show(await asyncio.to_thread(self.reader.read), events=False)
        await server.start()

    async def stop(self) -> None:
        """Stop listening."""
        if self._server is not None:
            await self._server.stop()
            self._server = None

    async def serve(self, stop: asyncio.Event) -> None:
        """Poll the store every ``poll_s`` seconds until ``stop`` is set."""
        while not stop.is_set():
            try:
                await asyncio.wait_for(stop.wait(), self.poll_s)
            except asyncio.TimeoutError:
                await self.refresh()

    async def refresh(self) -> None:
        """Read the store once and show what moved; raise an event for each state that changed.

        A read that fails marks every value uncertain (see the class docstring) instead of raising.
        """
        try:
            fleet = await asyncio.to_thread(self.reader.read)
        except (BacklashError, SQLAlchemyError, OSError) as exc:
            if self.read_error is None:
                for gearbox in self.objects.values():
                    await gearbox.mark_uncertain()
            reason = " ".join(f"{exc}".split())
            if reason != self.read_error and self.on_error is not None:
                self.on_error(reason)
            self.read_error = reason
            return
        if self.read_error is not None:
            self.read_error = None
            if self.on_error is not None:
                self.on_error(None)
        await self._show(fleet, events=True)

    async def _show(self, fleet: list[GearboxGauges], events: bool) -> None:
        for gauges in fleet:
            gearbox = self.objects.get(gauges.gearbox)
            if gearbox is None:
                gearbox = self.objects[gauges.gearbox] = await GearboxObject.create(
                    self._folder, self._idx, gauges.gearbox
                )
                assert self._server is not None
                self._events[gauges.gearbox] = await self._server.get_event_generator(
                    self._alarm_type, gearbox.node.nodeid
                )
            await gearbox.show(gauges)
            before = self.states.get(gauges.gearbox)
            self.states[gauges.gearbox] = gauges.state
            if events and gauges.state != before:
                await self._state_event(gauges, gearbox.node)

    async def _state_event(self, gauges: GearboxGauges, node: Node) -> None:
        play = "no play" if gauges.play_arcmin is None else f"play {gauges.play_arcmin:.2f} arcmin"
        message = f"{gauges.gearbox}: {gauges.state} ({gauges.state_reason}; {play})"
        when = utc(gauges.checked_unix_s)
        for generator in (self._events[gauges.gearbox], self._server_events):
            event = generator.event
            event.SourceNode = node.nodeid
            event.SourceName = gauges.gearbox
            event.Gearbox = gauges.gearbox
            event.State = gauges.state
            event.PlayArcmin = gauges.play_arcmin
            event.Severity = SEVERITY[gauges.state]
            event.ConditionName = "BacklashState"
            event.Retain = gauges.state in ("warning", "alarm")
            setattr(event, "ActiveState/Id", gauges.state in ("warning", "alarm"))
            event.ActiveState = ua.LocalizedText("Active" if gauges.state in ("warning", "alarm") else "Inactive")
            await generator.trigger(time_attr=when, message=message)
        if self.on_event is not None:
            self.on_event(gauges)
