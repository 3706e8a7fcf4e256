"""Recordings: one MCAP file per motion or homing, and the same messages served live.

``Recorder`` (recorder.py) hears the bus and the group and queues what it heard; the writer thread
(writer.py) turns it into the channels (channels.py: schemas and encodings), with the run's plan as
the drives execute it (planned.py), into the MCAP file (mcap_file.py, which reads recordings back too).
"""

from __future__ import annotations

from pvtflow.axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: ``pvtflow report`` reads without the writer)
_HOMES: dict[str, str] = {
    "Recorder": "pvtflow.service.recording.recorder",
    "Recorded": "pvtflow.service.recording.mcap_file",
    "Recording": "pvtflow.service.recording.mcap_file",
    "RecordingError": "pvtflow.service.recording.mcap_file",
    "read_recording": "pvtflow.service.recording.mcap_file",
}
__all__ = ["Recorded", "Recorder", "Recording", "RecordingError", "read_recording"]

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
