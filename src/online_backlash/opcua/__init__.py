"""The fleet over OPC UA for control rooms, SCADA and MES (``online-backlash opcua``; asyncua).

* :mod:`.model`: the information model: a folder of gearboxes, one object per gearbox, its variables.
* :mod:`.units`: UNECE-coded engineering units (``EUInformation``).
* :mod:`.settings`: the security settings and their checks (no asyncua: the CLI's parser reads them).
* :mod:`.security`: message security, the server's certificate, trusted clients, users.
* :mod:`.server`: :class:`~.server.PlantServer`, which follows the store and raises an event on a state change.

The store is read through :mod:`online_backlash.history` only (the figures of ``history --json``,
:mod:`online_backlash.history.gauges`); nothing a client sends can write. The submodules are
imported by name (asyncua loads only for ``opcua``).
"""
