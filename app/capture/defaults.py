"""Defaults of the device settings ``kogei capture`` can change.

One place for the values the drivers are built with (:func:`app.capture.devices.build_devices`)
and the values ``kogei capture --help`` states, so the two cannot drift apart.  Imports nothing:
the command line's parser reads it without loading the capture engine.
"""

from __future__ import annotations

__all__ = ["STEPS_PER_DEGREE", "SPEED_DEG_S", "EXPOSURE_US", "CAMERA_TIMEOUT_S", "HOTFOLDER_STABLE_S"]

#: Turntable motor steps per degree of table rotation: 3200 steps per revolution (the Horus turntable's).
STEPS_PER_DEGREE = 3200.0 / 360.0
#: Turntable speed (deg/s).
SPEED_DEG_S = 100.0
#: Laser profiler exposure (microseconds).
EXPOSURE_US = 500
#: Longest wait for one RAW frame from gphoto2 or a hot folder (s).
CAMERA_TIMEOUT_S = 60.0
#: How long a hot-folder file must keep its size before it is taken (s).
HOTFOLDER_STABLE_S = 1.0
