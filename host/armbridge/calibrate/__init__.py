"""`armbridge calibrate BOARD --port URL`: measure a board from its own sensors,
set what was found, persist it on the board and in a host file (docs/calibration.md).

base.py: what a board's procedure returns (Found) and the one flow every board
shares (calibrate_board); tuning.py: relay results -> PID gains; one module per
board's procedure (arm3r.py, masr.py, pump.py); command.py: the CLI.
"""
