"""The command-line entry points: ``python runners/<name>.py`` in a clone, ``sidewalk-<name>`` once installed."""
