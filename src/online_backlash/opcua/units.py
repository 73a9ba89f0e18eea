"""Engineering units of the OPC UA variables: ``EUInformation`` with UNECE Recommendation 20 codes.

OPC UA Part 8 (5.6.3, "EUInformation") names a unit by its UNECE common code, in the namespace
:data:`UNECE_NAMESPACE`, packed into the integer ``UnitId`` one byte per character (``"HUR"`` ->
``0x485552``); ``-1`` says that no code exists. The codes used here (UNECE Rec. 20, Annex I):
``DD`` degree [unit of angle], ``D61`` minute [unit of angle] (the arc minute), ``HUR`` hour.
A torsional stiffness in newton metre per arc minute has no UNECE code: its ``UnitId`` is -1 and
its display name says the unit.
"""

from __future__ import annotations

from asyncua import ua

#: The namespace of UNECE-coded units (OPC UA Part 8, 5.6.3).
UNECE_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"


def unit_id(common_code: str) -> int:
    """The ``UnitId`` of a UNECE common code: its characters as the bytes of an integer (OPC UA Part 8, 5.6.3).

    Examples
    --------
    >>> unit_id("HUR") == 0x485552, unit_id("DD") == 0x4444
    (True, True)
    """
    value = 0
    for char in common_code:
        value = (value << 8) | ord(char)
    return value


def eu_information(common_code: str | None, display: str, description: str) -> ua.EUInformation:
    """An ``EUInformation`` for a UNECE ``common_code`` (None: no code, ``UnitId`` -1)."""
    return ua.EUInformation(
        NamespaceUri=UNECE_NAMESPACE,
        UnitId=-1 if common_code is None else unit_id(common_code),
        DisplayName=ua.LocalizedText(display),
        Description=ua.LocalizedText(description),
    )


DEGREE = eu_information("DD", "°", "degree [unit of angle]")
ARCMIN = eu_information("D61", "′", "minute [unit of angle] (arc minute)")
HOUR = eu_information("HUR", "h", "hour (operating hours)")
NM_PER_ARCMIN = eu_information(None, "N·m/′", "newton metre per arc minute (torsional stiffness; no UNECE code)")
