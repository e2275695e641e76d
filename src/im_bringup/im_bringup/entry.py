"""
The executables of im_bringup: the console scripts of its ``setup.py``.

Each is started by :func:`im_common.startup.entry`, which takes the stop signals before the
heavy imports; light on purpose, this module imports nothing but :mod:`im_common.startup`.
"""
from im_common.startup import entry

scenario = entry('im_bringup.scenario:main')
commission = entry('im_bringup.commission:main')
live = entry('im_bringup.live:main')
