"""
The executables of im_recording: the console scripts of its ``setup.py``.

Each is started by :func:`im_common.startup.entry`, which takes the stop signals before the
heavy imports; light on purpose, this module imports nothing but :mod:`im_common.startup`.
"""
from im_common.startup import entry

record = entry('im_recording.record_node:main')
replay = entry('im_recording.replay:main')
report = entry('im_recording.report:main')
recover = entry('im_recording.recover:main')
