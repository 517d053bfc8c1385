"""Episodes as pictures: a run's evaluation episode or scripted agents played (``episodes``) and written as a GIF or
an MP4 (``video``), and the scenario gallery (``gallery``); ``runners/render.py`` is their command line. One world's
frame is drawn by ``sidewalk.envs.render``."""
