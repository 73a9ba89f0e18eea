"""CANopen servo drives: encoder objects found in the TPDO mapping of the object dictionary, samples grouped by SYNC or
paired in time.

The drive's EDS or DCF file is read with the ``canopen`` library (:func:`load_dictionary`); the
transmit PDOs are taken from its communication (0x1800 + n) and mapping (0x1A00 + n) parameters
(:func:`tpdos`; a DCF's values win over the EDS defaults, as in ``canopen``'s ``PdoMap.read(from_od=True)``).
The motor angle is *position actual value* 0x6064 of the motor node; the load angle is 0x6064 of a
second node (an encoder on the load shaft) or *additional position actual value* 0x60E4 of the
same node (:func:`find_encoder`). Counts per revolution come from the dictionary where it has them
(:func:`counts_per_rev`: position units per motor revolution = feed constant 0x6092 / gear ratio
0x6091 where the feed constant is set; with the feed constant at its unit default 1/1 the position
is in encoder increments, per the position encoder resolution 0x608F) or from the options.

Synchronous TPDOs (transmission type 0-240): one sample is what the SYNC producer asked for: the
SYNC frame (COB-ID 0x80 or the dictionary's 0x1005) opens a period, the TPDOs that carry the two
angles complete it, and the sample is timestamped at the SYNC frame (:class:`SyncPipeline`).

Event-driven TPDOs (transmission type 254 or 255, the common default of drives: sent on change
or on the event timer 0x1800+n.5, no SYNC): where either angle's TPDO is event-driven, the frames
are paired exactly as the DBC path pairs two messages without a counter
(:class:`~online_backlash.codecs.pairing.FramePipeline` with a :class:`PdoDecoder`): a motor value
and a load value at most ``max_skew_s`` apart form a sample, timestamped at the earlier frame; a
value replaced before its partner came is ``unpaired``; both angles in one TPDO make one sample
per frame. :func:`canopen_pipeline` picks the rule from the layout (:attr:`CanopenLayout.event_driven`).

Counting, as on the DBC path (:mod:`~online_backlash.codecs.pairing`); with SYNC:

- ``skipped``: frames that are not ours (other COB-IDs, heartbeats, extended IDs, remote and error frames);
- ``corrupt``: a SYNC or one of our PDOs with the wrong length (DLC), or a sample with a non-finite value;
- ``unpaired``: a SYNC period that ended without all its PDOs (its SYNC and the PDOs that came),
  a PDO outside a SYNC period, or one repeated within it (the older copy);
- ``gaps``: the SYNC counter (when the SYNC carries one; it runs 1 .. 0x1019) skips values, or the
  time between SYNCs is too long (the rule of :mod:`~online_backlash.codecs.gaps`).

Event-driven: SYNC frames and other COB-IDs are ``skipped``, a PDO of ours with the wrong length
``corrupt``, a value whose partner never came ``unpaired``. At the end (after ``flush()``)::

    frames == skipped + corrupt + unpaired + frames_per_sample * samples

Position values are 32-bit (or as mapped) integers that roll over; they are unwrapped by
:class:`~online_backlash.codecs.unwrap.Unwrapper` at ``2**bits``, so a multi-turn position runs on
through the rollover.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.objectdictionary.datatypes import INTEGER_TYPES, SIGNED_TYPES

from online_backlash.errors import FrameError, InvalidParameterError, LogFormatError
from online_backlash.stream import MAX_SKEW_S, Row

from .dbc import LOAD, MOTOR, DecodedFrame
from .pairing import CanCounters, FramePipeline, PerFramePipeline
from .sample_checks import SampleAssembler
from .unwrap import Unwrapper

#: Default COB-ID of the SYNC object (CiA 301), used when the dictionary has no 0x1005.
SYNC_COB_ID = 0x80
#: Largest value of the SYNC counter (CiA 301 0x1019), assumed when the dictionary does not give it.
SYNC_COUNTER_MAX = 240
POSITION_ACTUAL_VALUE = 0x6064
ADDITIONAL_POSITION_ACTUAL_VALUE = 0x60E4
POSITION_ENCODER_RESOLUTION = 0x608F
GEAR_RATIO = 0x6091
FEED_CONSTANT = 0x6092
COB_ID_SYNC = 0x1005
SYNC_COUNTER_OVERFLOW = 0x1019
TPDO_COMMUNICATION = 0x1800
TPDO_MAPPING = 0x1A00
_N_TPDO = 512
_PDO_NOT_VALID = 1 << 31
#: Transmission types 0-240 are synchronous (sent after a SYNC).
_LAST_SYNCHRONOUS = 240
#: Transmission types 254 (manufacturer-specific) and 255 (device profile): event-driven, sent on change or on the event
#: timer.
EVENT_DRIVEN = (254, 255)


def load_dictionary(path: str | os.PathLike[str], node_id: int) -> ObjectDictionary:
    """The object dictionary of node ``node_id`` (1-127) from an EDS or DCF file (``canopen.import_od``).

    Errors name the file: LogFormatError when it cannot be read, InvalidParameterError for a bad node-ID.
    """
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise InvalidParameterError(f"a CANopen node-ID is 1..127, got {node_id!r}")
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise LogFormatError(name, None, "no such object dictionary (EDS/DCF) file")
    try:
        return canopen.import_od(name, node_id)
    except Exception as exc:  # configparser, ObjectDictionaryError, ValueError for a suffix it does not read, ...
        raise LogFormatError(name, None, f"cannot read the object dictionary ({type(exc).__name__}: {exc})") from exc


def _od_value(od: ObjectDictionary, index: int, subindex: int = 0) -> Any:
    """The value of ``index.subindex`` (a DCF's value, else the EDS default); None where the dictionary has no such
    entry or value."""
    try:
        var = od.get_variable(index, subindex)
    except (KeyError, TypeError):
        return None
    if var is None:
        return None
    return var.value if var.value is not None else var.default


@dataclass(frozen=True)
class MappedObject:
    """One object mapped into a PDO: ``index.subindex`` (``name``), at ``bit_offset`` for ``bit_length`` bits."""

    index: int
    subindex: int
    name: str
    bit_offset: int
    bit_length: int
    signed: bool

    @property
    def label(self) -> str:
        """``0x6064.0 Position actual value``."""
        return f"0x{self.index:04X}.{self.subindex} {self.name}"

    def value(self, data: bytes | bytearray) -> int:
        """The object's integer value in a PDO's data bytes (little-endian, CiA 301)."""
        raw = (int.from_bytes(data, "little") >> self.bit_offset) & ((1 << self.bit_length) - 1)
        if self.signed and raw >> (self.bit_length - 1):
            raw -= 1 << self.bit_length
        return raw


@dataclass(frozen=True)
class Tpdo:
    """One transmit PDO of a node: its number (1-based), COB-ID, transmission type, mapped objects and length in
    bytes."""

    number: int
    node_id: int
    cob_id: int
    transmission_type: int
    objects: tuple[MappedObject, ...]
    length: int

    @property
    def name(self) -> str:
        """``TxPDO1_node3`` (canopen's naming)."""
        return f"TxPDO{self.number}_node{self.node_id}"

    def describe(self) -> str:
        """``TxPDO1_node3: 0x6064.0 Position actual value, ...``."""
        return f"{self.name}: " + ", ".join(o.label for o in self.objects)

    @property
    def trigger(self) -> str:
        """When the drive sends it (CiA 301 transmission type): ``sync``, ``event``, ``remote request`` or
        ``reserved``."""
        if self.transmission_type <= _LAST_SYNCHRONOUS:
            return "sync"
        if self.transmission_type in EVENT_DRIVEN:
            return "event"
        return "remote request" if self.transmission_type in (252, 253) else "reserved"

    def as_dict(self) -> dict[str, Any]:
        """The PDO as JSON values (``inspect --json``): number, name, COB-ID, transmission type and trigger, length in
        bytes, the objects mapped (``0x6064.0``, name, bit offset and length)."""
        objects = [
            {
                "object": f"0x{o.index:04X}.{o.subindex}",
                "name": o.name,
                "bit_offset": o.bit_offset,
                "bit_length": o.bit_length,
            }
            for o in self.objects
        ]
        return {
            "tpdo": self.number, "name": self.name, "cob_id": f"0x{self.cob_id:03X}",
            "transmission_type": self.transmission_type, "trigger": self.trigger, "length": self.length,
            "objects": objects,
        }  # fmt: skip


def tpdos(od: ObjectDictionary, node_id: int, path: str | os.PathLike[str] = "") -> list[Tpdo]:
    """The valid transmit PDOs of the dictionary (communication 0x1800 + n, mapping 0x1A00 + n).

    A PDO whose COB-ID has the not-valid bit set is left out; a communication record without a
    COB-ID gets the predefined one (0x180 + 0x100 n + node-ID, for TPDO 1-4). A mapping entry
    naming an object the dictionary lacks is a LogFormatError naming ``path`` and the entry.
    """
    found = []
    for n in range(_N_TPDO):
        if TPDO_COMMUNICATION + n not in od or TPDO_MAPPING + n not in od:
            continue
        cob_id = _od_value(od, TPDO_COMMUNICATION + n, 1)
        if cob_id is None:
            if n >= 4:
                continue
            cob_id = 0x180 + 0x100 * n + node_id
        if cob_id & _PDO_NOT_VALID:
            continue
        trans_type = _od_value(od, TPDO_COMMUNICATION + n, 2)
        objects, offset = [], 0
        for entry in range(1, (_od_value(od, TPDO_MAPPING + n, 0) or 0) + 1):
            mapping = _od_value(od, TPDO_MAPPING + n, entry) or 0
            index, subindex, bits = mapping >> 16, (mapping >> 8) & 0xFF, mapping & 0xFF
            if not (index and bits):
                continue
            var = od.get_variable(index, subindex)
            if var is None:
                raise LogFormatError(
                    path,
                    None,
                    f"0x{TPDO_MAPPING + n:04X}.{entry} maps 0x{index:04X}.{subindex}, which the dictionary lacks",
                )
            objects.append(MappedObject(index, subindex, var.name, offset, bits, var.data_type in SIGNED_TYPES))
            offset += bits
        found.append(
            Tpdo(
                n + 1,
                node_id,
                cob_id & 0x1FFFFFFF,
                255 if trans_type is None else int(trans_type),
                tuple(objects),
                (offset + 7) // 8,
            )
        )
    return found


def find_encoder(
    od: ObjectDictionary, node_id: int, path: str | os.PathLike[str], index: int, subindex: int | None = None
) -> tuple[Tpdo, MappedObject]:
    """The TPDO that carries ``index`` (``subindex``, or the first one mapped), and where.

    LogFormatError naming ``path`` and the object when the dictionary lacks it, when no TPDO maps it,
    when it is not an integer, or when its PDO is neither synchronous (transmission type 0-240) nor
    event-driven (254, 255): sent only on a remote request (252, 253) or a reserved type.
    """
    where = f"0x{index:04X}" if subindex is None else f"0x{index:04X}.{subindex}"
    if index not in od:
        raise LogFormatError(path, None, f"node {node_id}: the dictionary has no object {where}")
    mapped = [
        (pdo, obj)
        for pdo in tpdos(od, node_id, path)
        for obj in pdo.objects
        if obj.index == index and subindex in (None, obj.subindex)
    ]
    if not mapped:
        seen = ", ".join(p.describe() for p in tpdos(od, node_id, path)) or "no valid TPDO"
        raise LogFormatError(
            path, None, f"node {node_id}: object {where} is not mapped to any TPDO (0x1A00..); mapped: {seen}"
        )
    pdo, obj = mapped[0]
    var = od.get_variable(obj.index, obj.subindex)
    if not isinstance(var, ODVariable) or var.data_type not in INTEGER_TYPES:
        raise LogFormatError(path, None, f"node {node_id}: {obj.label} is not an integer object")
    if pdo.transmission_type > _LAST_SYNCHRONOUS and pdo.transmission_type not in EVENT_DRIVEN:
        raise LogFormatError(
            path,
            None,
            f"node {node_id}: {pdo.name} (0x{TPDO_COMMUNICATION + pdo.number - 1:04X}) has transmission type "
            f"{pdo.transmission_type}: neither synchronous (0-240) nor event-driven (254, 255)",
        )
    return pdo, obj


def _ratio(od: ObjectDictionary, index: int) -> float | None:
    """``sub1 / sub2`` of a CiA 402 ratio object (0x608F, 0x6091, 0x6092), None where absent or zero."""
    top, bottom = _od_value(od, index, 1), _od_value(od, index, 2)
    if not top or not bottom:
        return None
    return float(top) / float(bottom)


def counts_per_rev(
    od: ObjectDictionary, node_id: int, path: str | os.PathLike[str], given: float | None, option: str
) -> float:
    """Position units of 0x6064 per revolution of the node's shaft: ``given``, else feed constant 0x6092
    over gear ratio 0x6091 (CiA 402 factor group) where the feed constant is set, else position encoder
    resolution 0x608F (increments / motor revolutions); LogFormatError naming ``path``, the objects and
    ``option`` when none is known.

    A feed constant of 1/1 is the unit default of drives that leave the factor group alone (the
    ``canopen`` package's sample drive ``e35.eds``, 0x608F 2000/1): their position is in encoder
    increments, not in revolutions (1 per revolution would make every count 360 degrees).
    """
    if given is not None:
        return _positive(given, option)
    feed = _ratio(od, FEED_CONSTANT)
    if feed is not None and feed != 1.0:
        return feed / (_ratio(od, GEAR_RATIO) or 1.0)
    resolution = _ratio(od, POSITION_ENCODER_RESOLUTION)
    if resolution is not None:
        return resolution
    feed_note = "the feed constant 0x6092 is 1/1, the unit default, and " if feed is not None else ""
    missing = f"{feed_note}no position encoder resolution 0x608F; a set feed constant 0x6092 / gear ratio 0x6091 would"
    missing += " give them"
    raise LogFormatError(
        path, None, f"node {node_id}: no counts per revolution in the dictionary ({missing}): give {option}"
    )


def _positive(value: float, option: str) -> float:
    if not (math.isfinite(value) and value > 0):
        raise InvalidParameterError(f"{option} must be a positive number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Encoder:
    """An angle carried by a TPDO: ``obj`` in ``pdo`` of node ``pdo.node_id``, ``counts_per_rev`` counts per revolution
    of its shaft."""

    pdo: Tpdo
    obj: MappedObject
    counts_per_rev: float

    @property
    def modulus(self) -> int:
        """Where the value rolls over: ``2**bits``."""
        return 1 << self.obj.bit_length

    def degrees(self, count: float) -> float:
        """Degrees of the shaft for an unwrapped count."""
        return count * 360.0 / self.counts_per_rev

    def describe(self) -> str:
        """``node 3 0x6064.0 Position actual value in TxPDO1_node3 (COB-ID 0x183)``."""
        return f"node {self.pdo.node_id} {self.obj.label} in {self.pdo.name} (COB-ID 0x{self.pdo.cob_id:03X})"


def _sync_settings(od: ObjectDictionary) -> tuple[int, int | None]:
    """The SYNC COB-ID (0x1005, else 0x80) and the counter's overflow value (0x1019; 0 or 1: no counter; absent:
    240)."""
    cob_id = _od_value(od, COB_ID_SYNC, 0)
    overflow = _od_value(od, SYNC_COUNTER_OVERFLOW, 0) if SYNC_COUNTER_OVERFLOW in od else SYNC_COUNTER_MAX
    return (SYNC_COB_ID if cob_id is None else int(cob_id) & 0x7FF), (
        int(overflow) if overflow and overflow > 1 else None
    )


@dataclass(frozen=True)
class CanopenLayout:
    """Where the two angles are: the motor and load :class:`Encoder`, the SYNC COB-ID and counter overflow.

    Build it from the files with :meth:`from_files`.
    """

    motor: Encoder
    load: Encoder
    sync_cob_id: int = SYNC_COB_ID
    sync_overflow: int | None = SYNC_COUNTER_MAX

    @classmethod
    def from_files(
        cls,
        eds: str | os.PathLike[str],
        node: int,
        *,
        load_node: int | None = None,
        load_eds: str | os.PathLike[str] | None = None,
        load_subindex: int | None = None,
        motor_cpr: float | None = None,
        load_cpr: float | None = None,
    ) -> CanopenLayout:
        """Motor: 0x6064 of ``node`` (dictionary ``eds``). Load: 0x6064 of ``load_node`` (dictionary
        ``load_eds``, else ``eds``), or without ``load_node`` 0x60E4 of ``node`` (sub-index
        ``load_subindex`` or the first one mapped; counts per load revolution ``load_cpr`` are then
        required). Counts per revolution: see :func:`counts_per_rev`."""
        od = load_dictionary(eds, node)
        pdo, obj = find_encoder(od, node, eds, POSITION_ACTUAL_VALUE)
        motor = Encoder(pdo, obj, counts_per_rev(od, node, eds, motor_cpr, "--motor-cpr"))
        if load_node is None:
            if load_eds is not None:
                raise InvalidParameterError(
                    "--load-eds is the dictionary of the load encoder's node: give --load-node too"
                )
            pdo, obj = find_encoder(od, node, eds, ADDITIONAL_POSITION_ACTUAL_VALUE, load_subindex)
            if load_cpr is None:
                raise InvalidParameterError(
                    f"{os.fspath(eds)}: the load angle is {obj.label} of node {node}: give its counts per load "
                    "revolution (--load-cpr)"
                )
            load = Encoder(pdo, obj, _positive(load_cpr, "--load-cpr"))
        else:
            if load_node == node:
                raise InvalidParameterError(
                    f"--load-node {load_node} is the motor node: omit it to read 0x60E4 of that node"
                )
            if load_subindex is not None:
                raise InvalidParameterError(
                    "--load-subindex selects a sub-index of 0x60E4 on the motor node: not with --load-node"
                )
            load_path = eds if load_eds is None else load_eds
            load_od = load_dictionary(load_path, load_node)
            pdo, obj = find_encoder(load_od, load_node, load_path, POSITION_ACTUAL_VALUE)
            load = Encoder(pdo, obj, counts_per_rev(load_od, load_node, load_path, load_cpr, "--load-cpr"))
        return cls(motor, load, *_sync_settings(od))

    @property
    def event_driven(self) -> bool:
        """True where either angle's TPDO is event-driven (254, 255): samples are then paired in time, not grouped by
        SYNC."""
        return self.motor.pdo.transmission_type in EVENT_DRIVEN or self.load.pdo.transmission_type in EVENT_DRIVEN

    @property
    def pdo_lengths(self) -> dict[int, int]:
        """COB-ID -> length in bytes of each PDO a sample needs."""
        return {self.motor.pdo.cob_id: self.motor.pdo.length, self.load.pdo.cob_id: self.load.pdo.length}

    def names(self) -> dict[int, str]:
        """COB-ID -> what it is, for the frames of this layout (``inspect``): the SYNC (if used) and the two PDOs."""
        out = {} if self.event_driven else {self.sync_cob_id: "SYNC"}
        for role, enc in (("motor", self.motor), ("load", self.load)):
            text = f"{enc.pdo.describe()} ({role}: {enc.obj.label})"
            out[enc.pdo.cob_id] = (
                text
                if enc.pdo.cob_id not in out or role == "motor"
                else f"{out[enc.pdo.cob_id]}; load: {enc.obj.label}"
            )
        return out


@dataclass(frozen=True)
class NodeMapping:
    """What one node's dictionary says it sends (``inspect --eds``): its valid TPDOs and the SYNC COB-ID it consumes."""

    path: str
    node_id: int
    sync_cob_id: int
    tpdos: tuple[Tpdo, ...]

    @classmethod
    def read(cls, path: str | os.PathLike[str], node_id: int) -> NodeMapping:
        """The TPDO mapping of node ``node_id`` in the EDS/DCF at ``path`` (errors name the file:
        :func:`load_dictionary`, :func:`tpdos`)."""
        od = load_dictionary(path, node_id)
        return cls(os.fspath(path), node_id, _sync_settings(od)[0], tuple(tpdos(od, node_id, path)))

    def as_dict(self) -> dict[str, Any]:
        """JSON values: ``node``, ``eds``, ``sync_cob_id`` and ``tpdos`` (:meth:`Tpdo.as_dict`)."""
        return {
            "node": self.node_id,
            "eds": self.path,
            "sync_cob_id": f"0x{self.sync_cob_id:03X}",
            "tpdos": [p.as_dict() for p in self.tpdos],
        }


def cob_id_names(nodes: Sequence[NodeMapping]) -> dict[int, str]:
    """COB-ID -> what it carries, for ``inspect``: the SYNC and every valid TPDO (with its mapped
    objects) of each node; other COB-IDs by :func:`service_name`."""
    names: dict[int, str] = {}
    for node in nodes:
        names.setdefault(node.sync_cob_id, "SYNC")
        names.update({pdo.cob_id: pdo.describe() for pdo in node.tpdos})
    return names


def service_name(cob_id: int) -> str | None:
    """The CiA 301 predefined-connection-set service of a COB-ID (``NMT``, ``EMCY node 3``, ``TxPDO2 node 3``,
    ``SDO tx node 3``, ``heartbeat node 3`` ...), or None."""
    if cob_id == 0:
        return "NMT"
    if cob_id == 0x100:
        return "TIME"
    function, node = cob_id & 0x780, cob_id & 0x7F
    if not node:
        return None
    services = {0x080: "EMCY", 0x580: "SDO tx", 0x600: "SDO rx", 0x700: "heartbeat"}
    services.update({0x180 + 0x100 * n: f"TxPDO{n + 1}" for n in range(4)})
    services.update({0x200 + 0x100 * n: f"RxPDO{n + 1}" for n in range(4)})
    return f"{services[function]} node {node}" if function in services else None


class SyncPipeline(PerFramePipeline):
    """CAN frames in, one sample per SYNC period out: the rules of the module docstring.

    Parameters
    ----------
    layout : CanopenLayout
    period_s : float, optional
        Nominal SYNC period, seconds (learnt from the first steps if None), for gap detection.
    strict : bool
        Raise :class:`~online_backlash.errors.FrameError` at a corrupt frame instead of counting it.

    Attributes
    ----------
    counters : CanCounters
    frames_per_sample : int
        The SYNC plus the PDOs a sample needs (2 or 3).
    skew_mean_s, skew_max_s : float
        Mean and largest time from a SYNC to the last PDO of its sample, seconds.

    The per-frame :class:`~online_backlash.codecs.pairing.CanPipeline` interface (``feed_frames``,
    ``decode_frames``, ``flush``), and ``feed_row`` as the live notifier uses it; it keeps no DBC
    decoder, so it sets its own attributes instead of calling ``CanPipeline.__init__``.
    """

    def __init__(self, layout: CanopenLayout, period_s: float | None = None, strict: bool = False) -> None:
        self.layout = layout
        self.strict = strict
        self.max_skew_s = math.inf
        self.counters = CanCounters()
        self._lengths = layout.pdo_lengths
        self.frames_per_sample = 1 + len(self._lengths)
        self._modulus = layout.sync_overflow
        self._assemble = SampleAssembler(self.counters, self._modulus, period_s, strict).row
        self._motor_turns = Unwrapper(layout.motor.modulus)
        self._load_turns = Unwrapper(layout.load.modulus)
        self._sync: tuple[float, int | None] | None = None  # the open period: SYNC time, counter (0-based)
        self._got: dict[int, can.Message] = {}

    def flush(self) -> None:
        """End of stream: an open SYNC period without all its PDOs is unpaired."""
        self._close_period()

    def _decode(self, msg: can.Message) -> Row | None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self.counters.skipped += 1
            return None
        cob_id = msg.arbitration_id
        if cob_id == self.layout.sync_cob_id:
            self._on_sync(msg)
            return None
        length = self._lengths.get(cob_id)
        if length is None:
            self.counters.skipped += 1
            return None
        if msg.dlc != length or len(msg.data) != length:
            self._corrupt(f"PDO 0x{cob_id:03X} has {len(msg.data)} data bytes, its mapping {length}")
            return None
        if self._sync is None:  # no SYNC before it, or its period is complete already
            self.counters.unpaired += 1
            return None
        if cob_id in self._got:
            self.counters.unpaired += 1  # the older copy
        self._got[cob_id] = msg
        return self._complete() if len(self._got) == len(self._lengths) else None

    def _on_sync(self, msg: can.Message) -> None:
        self._close_period()
        counter: int | None = None
        if msg.dlc > 1 or len(msg.data) > 1:
            self._corrupt(f"SYNC with {len(msg.data)} data bytes (0 or 1: the counter)")
            return
        if len(msg.data) == 1 and self._modulus is not None:
            if not 1 <= msg.data[0] <= self._modulus:
                self._corrupt(f"SYNC counter {msg.data[0]} outside 1..{self._modulus}")
                return
            counter = msg.data[0] - 1
        self._sync = (msg.timestamp, counter)

    def _close_period(self) -> None:
        """An open period ends (a new SYNC, or the end): its SYNC and PDOs are unpaired."""
        if self._sync is not None:
            self.counters.unpaired += 1 + len(self._got)
        self._sync = None
        self._got = {}

    def _complete(self) -> Row | None:
        assert self._sync is not None
        time_s, counter = self._sync
        motor_msg, load_msg = self._got[self.layout.motor.pdo.cob_id], self._got[self.layout.load.pdo.cob_id]
        self._sync, self._got = None, {}
        self._add_skew(max(motor_msg.timestamp, load_msg.timestamp) - time_s)
        motor, load = self.layout.motor, self.layout.load
        return self._assemble(
            time_s,
            motor.degrees(self._motor_turns(motor.obj.value(motor_msg.data))),
            load.degrees(self._load_turns(load.obj.value(load_msg.data))),
            counter,
            self.frames_per_sample,
        )

    def _corrupt(self, reason: str) -> None:
        if self.strict:
            raise FrameError(reason)
        self.counters.corrupt += 1


class PdoDecoder:
    """The angles of event-driven TPDOs, read frame by frame for :class:`~online_backlash.codecs.pairing.FramePipeline`
    (the DBC path's pairing by time: the decoder interface of :class:`~online_backlash.codecs.dbc.DbcDecoder`).

    ``decode(msg)`` gives a :class:`~online_backlash.codecs.dbc.DecodedFrame` (raw counts, role
    MOTOR, LOAD, or both where one TPDO maps both angles) for a PDO of ours, None for any other
    frame (a SYNC included), and raises FrameError for one of ours with the wrong length.

    Attributes
    ----------
    motor, load : Encoder
        ``modulus`` and ``degrees`` of each angle.
    paired : bool
        True where the angles come in two TPDOs.
    counter_modulus : None
        PDOs carry no rolling counter: pairs are made by time.
    """

    counter_modulus: int | None = None

    def __init__(self, layout: CanopenLayout) -> None:
        self.motor, self.load = layout.motor, layout.load
        self.paired = layout.motor.pdo.cob_id != layout.load.pdo.cob_id
        roles = {layout.motor.pdo.cob_id: MOTOR}
        roles[layout.load.pdo.cob_id] = roles.get(layout.load.pdo.cob_id, 0) | LOAD
        self._by_id = {cob_id: (role, layout.pdo_lengths[cob_id]) for cob_id, role in roles.items()}

    def decode(self, msg: can.Message) -> DecodedFrame | None:
        """The raw counts ``msg`` carries, None if it is not one of our PDOs; FrameError if its length is wrong."""
        entry = self._by_id.get(msg.arbitration_id)
        if entry is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return None
        role, length = entry
        if msg.dlc != length or len(msg.data) != length:
            raise FrameError(f"PDO 0x{msg.arbitration_id:03X} has {len(msg.data)} data bytes, its mapping {length}")
        motor = self.motor.obj.value(msg.data) if role & MOTOR else 0
        load = self.load.obj.value(msg.data) if role & LOAD else 0
        return DecodedFrame(msg.timestamp, role, None, motor, load)


def canopen_pipeline(
    layout: CanopenLayout, period_s: float | None = None, max_skew_s: float = MAX_SKEW_S, strict: bool = False
) -> PerFramePipeline:
    """The frame rule of ``layout``: :class:`SyncPipeline` for synchronous TPDOs, else the DBC path's
    pairing by time (:class:`~online_backlash.codecs.pairing.FramePipeline` over a :class:`PdoDecoder`;
    ``max_skew_s``, seconds: the largest time between a motor and a load value of one sample).
    ``period_s``: the nominal sample period, seconds, for the gap rule (learnt if None)."""
    if layout.event_driven:
        return FramePipeline(PdoDecoder(layout), period_s, max_skew_s, strict)
    return SyncPipeline(layout, period_s, strict)
