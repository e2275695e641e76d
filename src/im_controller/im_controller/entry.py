"""
The executables of im_controller: the console scripts of its ``setup.py``.

Each is started by :func:`im_common.startup.entry`, which takes the stop signals before the
heavy imports; light on purpose, this module imports nothing but :mod:`im_common.startup`.
"""
from im_common.startup import entry

controller = entry('im_controller.controller_node:main')
design_gains = entry('im_controller.design_gains:main')
