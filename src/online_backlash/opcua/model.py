"""The OPC UA information model of the fleet: a folder of gearboxes, one object per gearbox, its variables.

::

    Objects
      Gearboxes                              (FolderType)
        GB-7                                 (BaseObjectType; an event notifier: its state changes)
          PlayDeg                 Double     AnalogUnitRangeType  °   EURange 0..5
          PlayArcmin              Double     AnalogUnitRangeType  ′   EURange 0..300
          PlayStdArcmin           Double     AnalogUnitType       ′
          PlayObservable          Boolean
          State                   String     ok | warning | alarm | unknown (as history --check)
          StateCode               Int32      0 | 1 | 2 | 3 (the plugin exit codes of history --check)
          StateReason             String
          WarnArcmin, LimitArcmin Double     AnalogUnitType       ′
          HoursToLimit            Double     AnalogUnitType       h   (operating hours; +inf: not reached)
          LastEstimateTime        DateTime
          StiffnessNmPerArcmin    Double     AnalogUnitType       N·m/′ (with a torque column)

Every variable is read-only (``AccessLevel`` CurrentRead). A figure that is not known (no estimate
yet, no level stored, no forecast) has no value and the status ``BadWaitingForInitialData``. The
play's variables carry the estimate's time as their source timestamp. The EURange of the play is
0..5 degrees, the span ``estimate`` reports without warning of wrong units or ratio. Units are
UNECE-coded ``EUInformation`` (:mod:`.units`).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from asyncua import Node, ua

from ..history.gauges import GearboxGauges
from .units import ARCMIN, DEGREE, HOUR, NM_PER_ARCMIN

#: The largest play the EURange of the play variables spans, degrees.
PLAY_RANGE_DEG = 5.0


@dataclass(frozen=True)
class Item:
    """One variable of a gearbox object: browse name, the gauge it shows, its type, unit and range."""

    name: str
    gauge: str
    variant: ua.VariantType
    unit: ua.EUInformation | None = None
    eu_range: tuple[float, float] | None = None
    #: The gauge's time (an attribute of :class:`GearboxGauges`, UNIX seconds) is the value's source timestamp.
    stamped: bool = False


ITEMS = (
    Item("PlayDeg", "play_deg", ua.VariantType.Double, DEGREE, (0.0, PLAY_RANGE_DEG), stamped=True),
    Item("PlayArcmin", "play_arcmin", ua.VariantType.Double, ARCMIN, (0.0, PLAY_RANGE_DEG * 60.0), stamped=True),
    Item("PlayStdArcmin", "play_std_arcmin", ua.VariantType.Double, ARCMIN, stamped=True),
    Item("PlayObservable", "play_observable", ua.VariantType.Boolean),
    Item("State", "state", ua.VariantType.String),
    Item("StateCode", "state_code", ua.VariantType.Int32),
    Item("StateReason", "state_reason", ua.VariantType.String),
    Item("WarnArcmin", "warn_arcmin", ua.VariantType.Double, ARCMIN),
    Item("LimitArcmin", "limit_arcmin", ua.VariantType.Double, ARCMIN),
    Item("HoursToLimit", "hours_to_limit", ua.VariantType.Double, HOUR),
    Item("LastEstimateTime", "last_estimate_time", ua.VariantType.DateTime),
    Item("StiffnessNmPerArcmin", "stiffness_nm_per_arcmin", ua.VariantType.Double, NM_PER_ARCMIN),
)

#: The data type node of each variant type used.
_DATA_TYPES = {
    ua.VariantType.Double: ua.ObjectIds.Double,
    ua.VariantType.Boolean: ua.ObjectIds.Boolean,
    ua.VariantType.String: ua.ObjectIds.String,
    ua.VariantType.Int32: ua.ObjectIds.Int32,
    ua.VariantType.DateTime: ua.ObjectIds.DateTime,
}


def utc(unix_s: float) -> ua.DateTime:
    """A UNIX time as an aware UTC datetime (OPC UA DateTime)."""
    return ua.DateTime.fromtimestamp(unix_s, dt.timezone.utc)


def node_id(idx: int, name: str | None = None) -> ua.NodeId:
    """The id of a new node in namespace ``idx``: ``name`` (a string id), or a number the server picks."""
    return ua.NodeId(ua.String(name) if name is not None else ua.Int32(0), ua.Int16(idx))


def type_id(object_id: int) -> ua.NodeId:
    """The id of a node of the standard namespace (a type, a data type)."""
    return ua.NodeId(ua.Int32(object_id))


def gauge_value(gauges: GearboxGauges, item: Item) -> Any:
    """The value ``item`` shows of a gearbox (None: not known)."""
    if item.gauge == "last_estimate_time":
        return None if gauges.last_estimate_unix_s is None else utc(gauges.last_estimate_unix_s)
    return getattr(gauges, item.gauge)


def data_value(gauges: GearboxGauges, item: Item) -> ua.DataValue:
    """The DataValue written to ``item``'s variable: the value, or ``BadWaitingForInitialData`` when not known."""
    value = gauge_value(gauges, item)
    now = ua.DateTime.now(dt.timezone.utc)
    if value is None:
        missing = ua.StatusCode(ua.UInt32(ua.StatusCodes.BadWaitingForInitialData))
        return ua.DataValue(StatusCode=missing, ServerTimestamp=now)
    source = utc(gauges.play_time_unix_s) if item.stamped and gauges.play_time_unix_s is not None else now
    return ua.DataValue(ua.Variant(value, item.variant), SourceTimestamp=source, ServerTimestamp=now)


async def add_item(parent: Node, idx: int, item: Item) -> Node:
    """``item`` as a variable of ``parent`` (namespace ``idx``): read-only, with its unit and range as properties.

    A variable with a unit is an ``AnalogUnitType`` (``EngineeringUnits``), with a range too an
    ``AnalogUnitRangeType`` (``EURange``) (OPC UA Part 8, 5.3.2).
    """
    if item.unit is None:
        type_definition = ua.ObjectIds.BaseDataVariableType
    else:
        type_definition = ua.ObjectIds.AnalogUnitType if item.eu_range is None else ua.ObjectIds.AnalogUnitRangeType
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(item.name)
    attrs.Description = ua.LocalizedText(item.name)
    attrs.DataType = type_id(_DATA_TYPES[item.variant])
    attrs.ValueRank = ua.ValueRank.Scalar
    attrs.Value = ua.Variant()  # no value until the first read of the store
    attrs.AccessLevel = attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
    attrs.WriteMask = attrs.UserWriteMask = 0
    add = ua.AddNodesItem()
    add.RequestedNewNodeId = node_id(idx)
    add.BrowseName = ua.QualifiedName(item.name, idx)
    add.NodeClass = ua.NodeClass.Variable
    add.ParentNodeId = parent.nodeid
    add.ReferenceTypeId = type_id(ua.ObjectIds.HasComponent)
    add.TypeDefinition = type_id(type_definition)
    add.NodeAttributes = attrs
    result = (await parent.session.add_nodes([add]))[0]
    result.StatusCode.check()
    node = Node(parent.session, result.AddedNodeId)
    if item.unit is not None:
        await node.add_property(node_id(idx), ua.QualifiedName("EngineeringUnits", 0), item.unit)
    if item.eu_range is not None:
        await node.add_property(node_id(idx), ua.QualifiedName("EURange", 0), ua.Range(*item.eu_range))
    return node


class GearboxObject:
    """One gearbox's object under the folder, and its variables (see the module docstring)."""

    def __init__(self, node: Node, variables: dict[str, Node]) -> None:
        self.node = node
        self.variables = variables

    @classmethod
    async def create(cls, folder: Node, idx: int, gearbox_id: str) -> GearboxObject:
        """The object of ``gearbox_id`` (its browse and display name) with every variable of :data:`ITEMS`."""
        node = await folder.add_object(node_id(idx, gearbox_id), ua.QualifiedName(gearbox_id, idx))
        variables = {item.name: await add_item(node, idx, item) for item in ITEMS}
        return cls(node, variables)

    async def show(self, gauges: GearboxGauges) -> None:
        """Write the gearbox's current figures into its variables."""
        for item in ITEMS:
            await self.variables[item.name].write_value(data_value(gauges, item))

    async def mark_uncertain(self) -> None:
        """Keep every value shown, with the status ``UncertainLastUsableValue`` (the store cannot be read)."""
        uncertain = ua.StatusCode(ua.UInt32(ua.StatusCodes.UncertainLastUsableValue))
        for node in self.variables.values():
            shown = await node.read_data_value(raise_on_bad_status=False)
            if shown.StatusCode is None or shown.StatusCode.is_good():
                now = ua.DateTime.now(dt.timezone.utc)
                stale = ua.DataValue(
                    Value=shown.Value, StatusCode=uncertain, SourceTimestamp=shown.SourceTimestamp, ServerTimestamp=now
                )
                await node.write_value(stale)
