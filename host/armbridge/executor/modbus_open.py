"""Opening a `modbus:` port for a session (the port table's opener, link/transport.py
SCHEMES): link/modbus.py's port, with an emulated board switched into Modbus first,
since it boots speaking the line protocol. The session itself is modbus_client.py's."""
from __future__ import annotations

import time

from armbridge.errors import ArmbridgeError
from armbridge.link.modbus import ModbusError, ModbusPort, ReadInputRegistersRequest


def open_modbus_port(url: str, baud: int = 115200, timeout: float | None = 0.1) -> ModbusPort:
    """`modbus:PORT?addr=N...` (link/modbus.py `open_modbus_port`), with an emulated board
    switched into Modbus first: it boots speaking the line protocol, and only a line
    session can tell it MODBUS addr (the port table, link/transport.py SCHEMES, names
    this opener)."""
    from armbridge.link.modbus import open_modbus_port as open_link

    port = open_link(url, baud, timeout)
    try:
        if port.emulator is not None:
            switch_to_modbus(port, port.master.addr)
    except BaseException:
        port.close()
        raise
    return port


def switch_to_modbus(port: ModbusPort, addr: int) -> None:
    """An emulated board boots speaking the line protocol (unless its EEPROM says Modbus):
    if it does not answer a Modbus read, open a line session and send MODBUS addr."""
    from armbridge.executor.client import BoardClient
    from armbridge.link.transport import PortError

    master = port.master
    try:
        master.request(ReadInputRegistersRequest(address=0, count=1), retries=0)
        return
    except ModbusError:
        pass
    client = BoardClient(port, None, connect_timeout=10.0)
    try:
        client.connect()
        client.command("MODBUS", addr)
    except ArmbridgeError as exc:
        raise PortError(f"cannot switch {port.inner_url} into Modbus: {exc}") from None
    end = port.clock() + 2.0 if port.clock else time.monotonic() + 2.0
    while True:
        try:
            master.read_input(0, 1)
            return
        except ModbusError as exc:
            if (port.clock() if port.clock else time.monotonic()) > end:
                raise PortError(f"{port.inner_url} took MODBUS {addr} but does not answer Modbus: {exc}") from None
