"""Telemetry: the Rerun recording of a run (`recording.py`), the layouts it opens in (`layout.py`) and `armbridge view` (`command.py`)."""
