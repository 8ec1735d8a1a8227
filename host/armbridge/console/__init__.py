"""`armbridge board`: talk to a board without a plan (identity, state, ping,
clear a latch, telemetry rate, a live monitor), on every port kind.

Verbs are subcommands with a common `--port`, as in mpremote and esptool;
read-only verbs take `--json`. Every verb opens a session through
`executor.session.open_session(port, robot=None, latched="allow")`, so a
latched board is shown as it is, never cleared behind the user's back.
"""
