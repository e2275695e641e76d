"""
The executables of im_observer: the console scripts of its ``setup.py``.

Each is started by :func:`im_common.startup.entry`, which takes the stop signals before the
heavy imports; light on purpose, this module imports nothing but :mod:`im_common.startup`.
"""
from im_common.startup import entry

observer = entry('im_observer.observer_node:main')
