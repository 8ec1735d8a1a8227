"""Links to boards: the host codec of the line protocol (`protocol`) and the
transports that carry it (`transport.open_port`: serial device, pyserial URL or
an in-process emulator `emu:DEVICE`)."""
