"""Telemetry: the Rerun recording of a run (`recording.py`) and `armbridge view` (`command.py`)."""
