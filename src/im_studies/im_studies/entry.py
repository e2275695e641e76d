"""
The executables of im_studies: the console scripts of its ``setup.py``.

Each is started by :func:`im_common.startup.entry`, which takes the stop signals before the
heavy imports; light on purpose, this module imports nothing but :mod:`im_common.startup`.
"""
from im_common.startup import entry

campaign = entry('im_studies.campaign:main')
efficiency_map = entry('im_studies.efficiency_map:main')
robust_study = entry('im_studies.robust_study:main')
